"""Declared configuration (enginebench/declare.py): each kind, bounds, choices, did-you-mean, rows; and
the methods, the CLI and the experiment spec that read their keys through it."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.declare import (Declaration, Field, Invalid, anything, choice, flag, listing, log_grid, number,
                                 positive, table, text, whole)
from enginebench.errors import MethodError, SpecError
from enginebench.method import Method
from enginebench.registry import available

D = Declaration(
    flag("standardize", True, "scale the features"),
    whole("centres", 2000, "Nystroem centres", low=1, unit="rows"),
    number("fraction", 0.25, "held-out share", low=0, high=1, low_open=True, high_open=True),
    positive("envelope", 10.0, "divergence envelope"),
    choice("solver", "auto", "which solver", ("auto", "exact", "falkon")),
    log_grid("gamma_grid", (-4, 4, 41), "kernel widths", searches=("gamma",)),
    listing("degrees", (1, 2), "degrees searched", items="int", low=1, high=5, searches=("degree",), edges="high"),
    text("device", "auto", "torch device"),
    table("extra", {}, "free table"),
    anything("payload", None, "anything at all"),
)


def check(**values):
    return D.validate(values, "method 'm'", MethodError)


def refusal(**values) -> str:
    with pytest.raises(MethodError) as err:
        check(**values)
    return str(err.value)


def test_defaults_are_filled_and_given_values_kept():
    out = check(centres=np.int64(7), fraction=0.5)
    assert out == {**D.defaults(), "centres": 7, "fraction": 0.5}
    assert type(out["centres"]) is int  # numpy scalars become plain


@pytest.mark.parametrize("values, message", [
    ({"standardize": 1}, "method 'm': option standardize must be true or false, got 1"),
    ({"centres": 0}, "method 'm': option centres must be a whole number >= 1, got 0"),
    ({"centres": 2.0}, "method 'm': option centres must be a whole number >= 1, got 2.0"),
    ({"centres": True}, "method 'm': option centres must be a whole number >= 1, got True"),
    ({"fraction": 1.0}, "method 'm': option fraction must be a number in (0, 1), got 1.0"),
    ({"fraction": 0}, "method 'm': option fraction must be a number in (0, 1), got 0"),
    ({"fraction": float("nan")}, "method 'm': option fraction must be a number in (0, 1), got nan"),
    ({"envelope": True}, "method 'm': option envelope must be a positive number, got True"),
    ({"envelope": float("inf")}, "method 'm': option envelope must be a positive number, got inf"),
    ({"solver": "magic"}, "method 'm': option solver='magic'; use one of 'auto', 'exact', 'falkon'"),
    ({"gamma_grid": (-1, True, 3)}, "method 'm': option gamma_grid=(-1, True, 3) must be (low exponent, high "
                                    "exponent, count) with 1 <= count <= 10000, e.g. (-4, 4, 41) for 10^-4 ... 10^4"),
    ({"gamma_grid": (-1, 1, 10**7)}, "method 'm': option gamma_grid=(-1, 1, 10000000) must be (low exponent, high "
                                     "exponent, count) with 1 <= count <= 10000"),
    ({"gamma_grid": (0, 1, 0)}, "method 'm': option gamma_grid=(0, 1, 0) must be (low exponent"),
    ({"degrees": [1, 6]}, "method 'm': option degrees must be a non-empty list of whole numbers in [1, 5], got [1, 6]"),
    ({"degrees": []}, "method 'm': option degrees must be a non-empty list"),
    ({"degrees": "12"}, "method 'm': option degrees must be a non-empty list"),
    ({"device": ""}, "method 'm': option device must be a non-empty string, got ''"),
    ({"extra": [1]}, "method 'm': option extra must be a table of name = value, got [1]"),
    ({"centre": 3}, "method 'm': unknown option(s) centre (did you mean 'centres'?); known: centres, degrees, "
                    "device, envelope, extra, fraction, gamma_grid, payload, solver, standardize"),
])
def test_refusals_are_one_line_naming_where_key_value_and_what(values, message):
    text_ = refusal(**values)
    assert text_.startswith(message) and "\n" not in text_


def test_bounds_inclusive_and_exclusive_edges():
    inclusive = Declaration(number("x", 0.0, "x", low=0, high=1))
    assert inclusive.validate({"x": 0}, "", MethodError)["x"] == 0
    assert inclusive.validate({"x": 1}, "", MethodError)["x"] == 1
    with pytest.raises(MethodError, match=r"^x must be a number in \[0, 1\], got 1.5$"):
        inclusive.validate({"x": 1.5}, "", MethodError, name="{key}")
    assert Field("x", 0, "", kind="int", high=3, high_open=True).bounds() == "< 3"


def test_choices_never_mistake_a_boolean_for_a_number():
    d = Declaration(choice("order", 0, "order", (0, 1)))
    assert d.validate({"order": 1}, "", MethodError)["order"] == 1
    with pytest.raises(MethodError, match="order=True; use 0 or 1"):
        d.validate({"order": True}, "", MethodError)


def test_nullable_message_check_and_any():
    d = Declaration(whole("rows", None, "rows", low=1, nullable=True),
                    anything("sign", "+", "sign", check=lambda v: v if v in "+-" else (_ for _ in ()).throw(
                        Invalid("{name}={value}; use '+' or '-'"))),
                    whole("n", 1, "n", low=0, message="{name} must be an integer >= 0 (0 = all), got {value}"))
    assert d.validate({"rows": None, "sign": "-"}, "", MethodError) == {"rows": None, "sign": "-", "n": 1}
    with pytest.raises(MethodError, match=r"^w: option sign='x'; use '\+' or '-'$"):
        d.validate({"sign": "x"}, "w", MethodError)
    with pytest.raises(MethodError, match=r"^w: option n must be an integer >= 0 \(0 = all\), got -1$"):
        d.validate({"n": -1}, "w", MethodError)
    with pytest.raises(MethodError, match="option rows must be a whole number >= 1 or None, got 0"):
        d.validate({"rows": 0}, "w", MethodError)


def test_strict_false_lets_undeclared_keys_pass_and_fill_false_adds_no_defaults():
    out = D.validate({"source": {"run": 1}, "centres": 3}, "", MethodError, fill=False, strict=False)
    assert out == {"source": {"run": 1}, "centres": 3}


def test_rows_edges_extend_and_with_defaults():
    rows = {r[0]: r for r in D.rows()}
    assert rows["centres"] == ("centres", "int >= 1", "2000", "rows", "Nystroem centres")
    assert rows["solver"][1:3] == ("choice: auto | exact | falkon", '"auto"')
    assert rows["fraction"][1] == "float in (0, 1)"
    assert rows["gamma_grid"][2] == "[-4, 4, 41]" and rows["payload"][1:3] == ("any", "None")
    assert D.edges() == {"gamma": "both", "degree": "high"}
    more = D.extend(whole("centres", 10, "fewer centres", low=1), flag("new", False, "a new switch"))
    assert more.names() == [*D.names(), "new"] and more["centres"].default == 10
    assert D.with_defaults(solver="exact").defaults()["solver"] == "exact"
    with pytest.raises(ValueError, match="declared twice"):
        Declaration(flag("a", True, ""), flag("a", False, ""))
    with pytest.raises(ValueError, match="kind 'complex'"):
        Field("a", 0, "", kind="complex")


# -- methods --------------------------------------------------------------------------------------
BUILTIN = {name: cls for name, cls in available().items() if cls.__module__.startswith("enginebench.methods")}


@pytest.mark.parametrize("name", sorted(BUILTIN))
def test_every_builtin_method_declares_each_option_with_a_meaning(name):
    cls = BUILTIN[name]
    declared = cls.option_declaration()
    assert list(cls.default_options()) == declared.names()
    assert all(f.kind != "any" or f.check is not None or f.type_label for f in declared), name
    assert not [f.name for f in declared if not f.meaning.strip()]
    declared.validate(cls.default_options(), f"method {name!r}", MethodError)  # the defaults pass their own checks
    assert set(cls.grid_edges().values()) <= {"both", "low", "high", "none"}


def test_unknown_option_of_nfir_names_nfir_and_suggests():
    from enginebench.methods.nfir import NFIR

    with pytest.raises(MethodError, match=r"^method 'nfir': unknown option\(s\) max_lag \(did you mean 'max_lags'\?\)"):
        NFIR(max_lag=4)
    with pytest.raises(MethodError, match=r"^method 'nfir': option solver must be one of auto, exact, falkon"):
        NFIR(solver="magic")


def test_grid_edges_of_builtins():
    from enginebench.methods.krls import KRLS
    from enginebench.methods.sindy import SINDy

    assert SINDy.grid_edges() == {"order": "both", "degree": "high", "threshold": "both", "alpha": "both"}
    assert KRLS.grid_edges() == {"gamma": "both", "lambda": "both"}


class OnlyDefaults(Method):
    """A plugin that overrides default_options alone (no declaration)."""

    name = "only-defaults"

    @classmethod
    def default_options(cls):
        return {"alpha": 1.0, "mode": "x"}


def test_plugins_that_only_override_default_options_still_work():
    m = OnlyDefaults(alpha="anything")
    assert m.options == {"alpha": "anything", "mode": "x"}
    assert [r[1] for r in OnlyDefaults.option_declaration().rows()] == ["any", "any"]
    with pytest.raises(MethodError, match=r"^method 'only-defaults': unknown option\(s\) alpah \(did you mean "):
        OnlyDefaults(alpah=2)


def test_methods_show_lists_every_option_with_its_meaning():
    from enginebench.methods.krls import KRLS

    out = CliRunner().invoke(cli, ["methods", "show", "krls"])
    assert out.exit_code == 0, out.output
    lines = out.output.splitlines()
    head = next(i for i, line in enumerate(lines) if line.split()[:5] == ["option", "type", "default", "unit", "meaning"])
    table_ = lines[head + 2:head + 2 + len(KRLS.declared_options.fields)]  # after the header's rule
    bounds = {"gamma_grid": "; extended at its edges, >= 1e-08 and <= 1e+06 (gamma)",
              "lambda_grid": "; extended at its edges, >= 1e-14 and <= 1e+08 (lambda)"}
    for f, line in zip(KRLS.declared_options, table_):
        assert line.split()[0] == f.name and line.rstrip().endswith(f.meaning + bounds.get(f.name, ""))
    assert any(line.split()[:3] == ["centres", "int", ">="] and " rows " in line for line in table_)


# -- the experiment spec ----------------------------------------------------------------------------
def test_a_bad_split_key_is_one_spec_error_before_any_data_is_read(tmp_path):
    spec = tmp_path / "e.toml"
    spec.write_text('dataset = "absent.parquet"\ntargets = ["y"]\nmethods = ["krls"]\n'
                    '[split]\nkind = "holdout"\ntest_frac = 0.2\n')
    out = CliRunner().invoke(cli, ["run", str(spec)])
    assert out.exit_code == 2
    assert out.output.strip() == (f"error: {spec}: [split] kind = 'holdout': unknown key(s) test_frac (did you mean "
                                  "'test_fraction'?); allowed: kind, test_fraction, validation_fraction")


def test_split_values_are_checked_when_the_spec_is_read():
    from enginebench.experiments.spec import from_dict

    base = {"dataset": "x.parquet", "targets": ["y"], "methods": ["krls"]}
    with pytest.raises(SpecError, match=r"^t: \[split\] folds must be a whole number >= 1, got 0$"):
        from_dict({**base, "split": {"kind": "rolling", "folds": 0}}, origin="t")
    with pytest.raises(SpecError, match=r"^t: \[selection\]: unknown key\(s\) kidn \(did you mean 'kind'\?\)"):
        from_dict({**base, "selection": {"kidn": "kfold"}}, origin="t")
