"""``-o`` into what is not a regular file: written as it is, never replaced by a file; a pipe without a reader
and a socket are refused with one line instead of a hang."""

from __future__ import annotations

import os
import socket
import stat
import threading

import pytest

from enginebench.errors import DataError
from enginebench.results.output import write_output


def test_dev_null_stays_a_device():
    write_output("/dev/null", "table\n")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_a_symbolic_link_is_written_through_and_kept(tmp_path):
    target = tmp_path / "real.md"
    target.write_text("old old old")
    link = tmp_path / "link.md"
    link.symlink_to(target)
    write_output(link, "new\n")
    assert link.is_symlink() and target.read_text() == "new\n"


def test_a_named_pipe_is_written_to_its_reader(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader is there
    reader = threading.Thread(target=lambda: got.append(os.read(fd, 100)))
    write_output(fifo, "rows\n")
    reader.start()
    reader.join(5)
    os.close(fd)
    assert got == [b"rows\n"] and stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_a_named_pipe_without_reader_is_refused_at_once(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(DataError, match="a named pipe with no reader; start the reader first"):
        write_output(fifo, "rows\n")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_a_socket_is_refused(tmp_path):
    path = tmp_path / "s.sock"
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(path))
    try:
        with pytest.raises(DataError, match="it is a socket"):
            write_output(path, "x")
    finally:
        server.close()
