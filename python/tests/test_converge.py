"""gilab.converge() is `gilab converge`: same summary, same error columns, same files."""

from __future__ import annotations

import csv
import json
import pathlib

import gilab

EXPERIMENT = pathlib.Path(__file__).parent / "data" / "tiny-converge.toml"
ERRORS = ("mse", "rel_mse", "smape", "flip")


def _stable(summary: dict) -> dict:
    """The summary without what differs between two runs of one experiment (times, clocks)."""
    keep = ("experiment", "file", "preset_sha256", "git_commit", "size", "seeds", "settings",
            "total_runs", "references")
    run_keep = ("spec", "params", "rays_per_pixel_per_frame", "frames", "passes_run",
                "passes_skipped", "final_mse", "final_rel_mse", "final_smape", "final_flip",
                "non_finite_pixels", "image")
    return {
        **{k: summary[k] for k in keep},
        "runs": [{k: r[k] for k in run_keep} for r in summary["runs"]],
    }


def test_converge_equals_cli(run_cli, tmp_path):
    cli_out, py_out = tmp_path / "cli", tmp_path / "py"
    cache = tmp_path / "cache"
    run_cli("converge", str(EXPERIMENT), "--out", str(cli_out), "--cache", str(cache))
    summary, rows = gilab.converge(EXPERIMENT, out=py_out, cache=cache, as_frame=False)
    cli_summary = json.loads((cli_out / "summary.json").read_text())
    assert _stable(summary) == _stable(cli_summary)
    assert summary["runs"] and len(summary["runs"]) == len(cli_summary["runs"])
    with open(cli_out / "convergence.csv") as f:
        cli_rows = list(csv.DictReader(f))
    assert len(rows) == len(cli_rows) == 2 * 4
    for ours, theirs in zip(rows, cli_rows):
        assert (ours["label"], ours["frame"]) == (theirs["label"], int(theirs["frame"]))
        # Errors are deterministic: bit-identical columns (the CSV prints f64 round-trip).
        for key in ERRORS:
            assert float(theirs[key]) == ours[key], key
        assert int(theirs["rays"]) == ours["rays"]
    for name in ("report.md", "summary.json", "convergence.csv", "error_vs_time.png"):
        assert (py_out / name).is_file(), name


def test_converge_from_dict(tmp_path):
    # The experiment as a dict (the TOML file's tables), one run of two frames.
    experiment = {
        "scene": {"source": "cornell"},
        "render": {"size": [32, 32], "seed": 1, "reference_spp": 16},
        "techniques": [{"name": "reference"}],
        "experiment": {"frames": 2, "metric": "rel_mse"},
    }
    summary, rows = gilab.converge(
        experiment, out=tmp_path / "out", cache=tmp_path / "cache", progress=False, as_frame=False
    )
    assert [r["frame"] for r in rows] == [1, 2]
    assert all(r["rel_mse"] > 0 for r in rows)
    assert summary["runs"][0]["spec"]["label"] == "reference"
    assert (tmp_path / "out" / "report.md").is_file()


def test_converge_rows_as_dataframe_with_pandas(tmp_path, monkeypatch):
    """With pandas importable, the rows come back as its DataFrame (a stand-in module here:
    CI does not install pandas)."""
    import sys
    import types

    fake = types.ModuleType("pandas")
    fake.DataFrame = lambda rows: ("DataFrame", rows)
    monkeypatch.setitem(sys.modules, "pandas", fake)
    experiment = {
        "scene": {"source": "cornell"},
        "render": {"size": [16, 16], "reference_spp": 4},
        "techniques": [{"name": "reference"}],
        "experiment": {"frames": 1},
    }
    _, rows = gilab.converge(experiment, out=tmp_path / "o", cache=tmp_path / "c", progress=False)
    assert rows[0] == "DataFrame" and rows[1][0]["frame"] == 1
