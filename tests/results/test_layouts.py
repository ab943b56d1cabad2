"""Paper table layouts: turboshaft-moe's Tables 2-3 and egt-hybrid's Tables 8-9 (formerly seed 003 / seed 000)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import scipy.stats
from click.testing import CliRunner

from enginebench.errors import DataError
from enginebench.results.layouts import (
    LITERATURE, THIS_RUN, egt_hybrid_markdown, egt_hybrid_table, read_literature, turboshaft_moe_markdown,
    turboshaft_moe_paired, turboshaft_moe_table,
)

SEG_METRICS = ("rmae", "rmae_seg_sd", "rmae_seg_median", "rmae_seg_iqr", "diverged", "n_segments")


def job_rows(methods: dict[str, float], reps: int = 4, target: str = "TRQ", seed: int = 0, failed: tuple = ()) -> pd.DataFrame:
    """Long metric rows as jobs write them: per method, repetition and split, one row per metric."""
    rng = np.random.default_rng(seed)
    rows = []
    for method, level in methods.items():
        for r in range(reps):
            base = {"dataset": "turboshaft", "target": target, "mode": "simulation", "window": 0.0, "method": method,
                    "family": "x", "repetition": r}
            if (method, r) in failed:
                rows.append({**base, "split": "-", "metric": "failed", "value": np.nan, "status": "failed"})
                continue
            for split, n_seg in (("validation", 8), ("test", 6)):
                vals = {"rmae": level + rng.normal(0, 0.3), "rmae_seg_sd": 1 + rng.uniform(), "rmae_seg_median": level,
                        "rmae_seg_iqr": rng.uniform(), "diverged": float(r % 2), "n_segments": float(n_seg), "mae": 9.0}
                rows += [{**base, "split": split, "metric": m, "value": v, "status": "ok"} for m, v in vals.items()]
            rows.append({**base, "split": "-", "metric": "time_fit_s", "value": 1.0, "status": "ok"})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def trq():
    return job_rows({"nfir": 4.0, "moe-nfir": 2.5, "sindy-nfir": 2.0, "moe[ideal]": 1.0}, failed=(("moe-nfir", 3),))


def test_seed003_cells_are_repetition_means_of_the_job_rows(trq):
    table = turboshaft_moe_table(trq, literature=False)
    assert list(table["method"]) == ["nfir", "moe[ideal]", "moe-nfir", "sindy-nfir"]  # the paper's row order
    ok = trq[trq["status"] == "ok"]
    for row in table.itertuples():
        for split, prefix in (("validation", "val"), ("test", "test")):
            sel = ok[(ok["method"] == row.method) & (ok["split"] == split)]
            for metric, suffix in zip(SEG_METRICS, ("mean", "sd", "median", "iqr", "diverged", "trajectories")):
                expected = sel.loc[sel["metric"] == metric, "value"].mean()
                assert getattr(row, f"{prefix}_{suffix}") == pytest.approx(expected, rel=1e-12)
    moe = table.set_index("method").loc["moe-nfir"]
    assert (moe["n_repeats"], moe["n_failed"]) == (3, 1)
    assert table.set_index("method").loc["nfir", "test_diverged"] == pytest.approx(0.5)  # 1 of 2 repetitions, 1 each
    assert set(table["source"]) == {THIS_RUN}


def test_seed003_literature_rows_come_from_the_published_tables(trq):
    table = turboshaft_moe_table(pd.concat([trq, job_rows({"nfir": 3.0}, target="WF")]))
    lit = table[table["source"] == LITERATURE].set_index(["target", "method"])
    assert lit.loc[("TRQ", "sindy-nfir"), "test_mean"] == pytest.approx(2.34)
    assert lit.loc[("TRQ", "moe[ideal]"), "val_iqr"] == pytest.approx(0.80)
    assert lit.loc[("WF", "sindy"), "test_mean"] == pytest.approx(1e8)  # the paper's (1 +- 8) x 10^8
    assert lit.loc[("WF", "sindy"), "test_sd"] == pytest.approx(8e8)
    assert len(lit) == 9 and LITERATURE == "literature (confidential data; not comparable)"
    # literature rows follow each target's own rows
    assert list(table["target"]) == ["TRQ"] * (4 + 6) + ["WF"] * (1 + 3)
    assert (table[table["target"] == "TRQ"]["source"].iloc[:4] == THIS_RUN).all()


def test_seed003_paired_test_between_the_two_best_run_time_methods(trq):
    p = turboshaft_moe_paired(trq).iloc[0]
    assert (p["best"], p["second"]) == ("sindy-nfir", "moe-nfir")  # moe[ideal] is better but not available at run time
    ok = trq[(trq["status"] == "ok") & (trq["split"] == "test") & (trq["metric"] == "rmae")]
    wide = ok.pivot_table(index="repetition", columns="method", values="value").dropna(subset=["moe-nfir"])
    assert p["n_pairs"] == 3
    assert p["t_pvalue"] == pytest.approx(scipy.stats.ttest_rel(wide["moe-nfir"], wide["sindy-nfir"]).pvalue, rel=1e-12)
    assert p["wilcoxon_pvalue"] == pytest.approx(scipy.stats.wilcoxon(wide["moe-nfir"], wide["sindy-nfir"]).pvalue)
    assert p["mean_difference"] == pytest.approx((wide["moe-nfir"] - wide["sindy-nfir"]).mean())


def test_seed003_paired_with_one_repetition_says_why_there_is_no_test():
    p = turboshaft_moe_paired(job_rows({"a": 2.0, "b": 3.0}, reps=1)).iloc[0]
    assert np.isnan(p["t_pvalue"]) and p["note"] == "only 1 paired repetition(s); a paired test needs at least 2"


def test_seed003_markdown_labels_literature_and_ideal_and_bolds_the_best_run_time_row(trq):
    md = turboshaft_moe_markdown(turboshaft_moe_table(trq), turboshaft_moe_paired(trq), dataset="turboshaft (synthetic)")
    lines = md.splitlines()
    assert lines[0] == "### TRQ: RMAE (%) over trajectories — turboshaft (synthetic)"
    ideal = next(line for line in lines if line.startswith("| *moe[ideal]* | this run"))
    assert "**" not in ideal  # ideal rows never take the bold
    best = next(line for line in lines if line.startswith("| sindy-nfir | this run"))
    assert best.count("**") >= 4
    assert sum(LITERATURE in line for line in lines) == 6
    assert "NOT available at run time" in md and "moe-nfir - sindy-nfir" in md


def test_seed003_needs_validation_or_test_rows():
    rows = job_rows({"nfir": 1.0})
    rows = rows[~rows["split"].isin(["validation", "test"])]
    with pytest.raises(DataError, match="turboshaft-moe layout: the run has no rmae rows on the validation or test part"):
        turboshaft_moe_table(rows)


# -- egt-hybrid (formerly seed 000) ---------------------------------------------------------------
def marine_rows(reps: int = 5) -> pd.DataFrame:
    rng = np.random.default_rng(1)
    rows = []
    for window in (0.0, 20.0):
        for method, mae in (("krls", 8.0), ("mtl-krls", 6.0)):
            for r in range(reps):
                base = {"target": "t_exhaust_turbine_outlet", "mode": "window", "window": window, "method": method,
                        "repetition": r, "status": "ok", "split": "test"}
                for m, v in (("mae", mae + rng.normal()), ("mape", 2 + rng.normal(0, 0.1)), ("ppmcc", 0.99 - rng.uniform(0, 0.01))):
                    rows.append({**base, "metric": m, "value": v})
    return pd.DataFrame(rows)


def test_seed000_cells_are_means_with_student_t_half_widths():
    rows = marine_rows()
    table = egt_hybrid_table(rows, literature=False)
    assert list(zip(table["window"], table["method"])) == [(0.0, "krls"), (0.0, "mtl-krls"), (20.0, "krls"), (20.0, "mtl-krls")]
    for r in table.itertuples():
        for m in ("mae", "mape", "ppmcc"):
            v = rows[(rows["window"] == r.window) & (rows["method"] == r.method) & (rows["metric"] == m)]["value"].to_numpy()
            half = scipy.stats.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v))
            assert getattr(r, m) == pytest.approx(v.mean(), rel=1e-12)
            assert getattr(r, f"{m}_ci") == pytest.approx(half, rel=1e-10)


def test_seed000_literature_rows_and_markdown():
    table = egt_hybrid_table(marine_rows())
    lit = table[table["source"] == LITERATURE]
    pm = lit[(lit["method"] == "pm") & (lit["window"] == 0)].iloc[0]
    assert (pm["mae"], pm["mae_ci"], pm["mape"], pm["ppmcc"]) == (33.0, 1.7, 11.7, 0.86)  # egt-hybrid Table 8
    assert len(lit) == 9 and set(lit["target"]) == {"t_exhaust_turbine_outlet"}
    assert len(read_literature("literature-seed000.csv")) == 18
    md = egt_hybrid_markdown(table)
    assert "| 0 | pm | literature (confidential data; not comparable) | 33 ± 1.7 | 11.7 ± 0.5 | 0.86 ± 0.05 | 30 |" in md
    assert "Student-t 95% interval" in md


# -- command line --------------------------------------------------------------------------------------
def test_layout_command_merges_runs_and_refuses_overlaps(tmp_path, trq):
    import click

    from enginebench.cli.layout import layout
    from enginebench.results.store import RunStore

    store = RunStore(tmp_path)
    refs = []
    for name, rows in (("trq", trq), ("wf", job_rows({"nfir": 3.0}, target="WF"))):
        run = store.create(name, {"dataset": "turboshaft"}, "abc123", {}, 1)
        run.write_job("all", rows, {"status": "ok"})
        refs.append(run.id)
    group = click.Group(commands={"layout": layout})
    res = CliRunner().invoke(group, ["layout", *refs, "--seed003", "--store", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "### TRQ: RMAE (%)" in res.output and "### WF: RMAE (%)" in res.output
    res = CliRunner().invoke(group, ["layout", refs[0], refs[0], "--store", str(tmp_path)])
    assert res.exit_code == 0 and res.output.count("| nfir | this run") == 1  # the same run twice counts once
    twin = store.create("trq-again", {"dataset": "turboshaft"}, "abc124", {}, 1)
    twin.write_job("all", trq, {"status": "ok"})
    res = CliRunner().invoke(group, ["layout", refs[0], twin.id, "--store", str(tmp_path)])
    assert isinstance(res.exception, DataError) and "both hold method 'nfir' for target 'TRQ'" in str(res.exception)


def test_the_papers_stable_names_and_the_old_seed_names_are_the_same_layouts(tmp_path, trq):
    import click

    from enginebench.cli.layout import layout
    from enginebench.results.store import RunStore

    assert read_literature("literature-turboshaft-moe.csv").equals(read_literature("literature-seed003.csv"))
    run = RunStore(tmp_path).create("trq", {"dataset": "turboshaft"}, "abc123", {}, 1)
    run.write_job("all", trq, {"status": "ok"})
    group = click.Group(commands={"layout": layout})

    def invoke(*flags):
        return CliRunner().invoke(group, ["layout", run.id, *flags, "--store", str(tmp_path)])

    new, old, default = invoke("--paper", "turboshaft-moe"), invoke("--seed003"), invoke()
    assert new.exit_code == old.exit_code == default.exit_code == 0, old.output
    assert new.stdout == old.stdout == default.stdout and "### TRQ: RMAE (%)" in new.stdout
    assert old.stderr == "note: --seed003 is deprecated (a seed is a random seed); use --paper turboshaft-moe\n"
    assert new.stderr == default.stderr == ""
    assert "turboshaft-moe paper, Tables 2-3" in new.stdout
    clash = invoke("--paper", "egt-hybrid", "--seed003")
    assert clash.exit_code == 2 and "--paper egt-hybrid and --seed003 ask for different layouts" in clash.output
    help_text = CliRunner().invoke(group, ["layout", "--help"]).output
    assert "--paper [turboshaft-moe|egt-hybrid]" in help_text and "--seed003" not in help_text  # hidden alias


def test_egt_hybrid_layout_by_its_new_and_old_flags(tmp_path):
    import click

    from enginebench.cli.layout import layout
    from enginebench.results.store import RunStore

    run = RunStore(tmp_path).create("egt", {"dataset": "marine-diesel"}, "abc123", {}, 1)
    run.write_job("all", marine_rows().assign(dataset="marine-diesel", family="x"), {"status": "ok"})
    group = click.Group(commands={"layout": layout})
    new = CliRunner().invoke(group, ["layout", run.id, "--paper", "egt-hybrid", "--store", str(tmp_path)])
    old = CliRunner().invoke(group, ["layout", run.id, "--seed000", "--store", str(tmp_path)])
    assert new.exit_code == old.exit_code == 0, old.output
    assert new.stdout == old.stdout and "| 0 | pm | literature (confidential data; not comparable) | 33 ± 1.7" in new.stdout
    assert old.stderr == "note: --seed000 is deprecated (a seed is a random seed); use --paper egt-hybrid\n"
