"""``h4bench compare``: two runs' first differing stage, then their other differences; the platform and timings
never count."""

import json

from typer.testing import CliRunner

from h4bench.scenarios.cli import app
from h4bench.scenarios.compare import compare_results, first_stage

HASHES = {"trajectory": "a" * 64, "controller": "b" * 64, "feedforward": "c" * 64, "dataset": "d" * 64}
RUN = {"content_hashes": HASHES, "methods": {"hull": {"lower": [0.1, 0.2], "upper": [0.3, 0.4], "enclosed": True}},
       "timings": {"simulation": 1.0}, "platform": {"blas": [{"kernel": "Haswell", "threads": 2}]}}


def _other(**changes):
    out = json.loads(json.dumps(RUN))
    out["timings"]["simulation"] = 2.0
    out["platform"]["blas"][0]["kernel"] = "Sandybridge"
    for stage, value in changes.get("hashes", {}).items():
        out["content_hashes"][stage] = value
    if "lower" in changes:
        out["methods"]["hull"]["lower"] = changes["lower"]
    return out


def test_first_stage_is_the_earliest_differing_hash():
    assert first_stage(RUN, _other()) is None
    assert first_stage(RUN, _other(hashes={"dataset": "0" * 64, "controller": "1" * 64})) == "controller"
    assert first_stage(RUN, {k: v for k, v in RUN.items() if k != "content_hashes"}) == "trajectory"


def test_compare_results_ignores_platform_and_timings_but_not_boxes():
    lines, count = compare_results(RUN, _other())
    assert count == 0 and lines[0].startswith("same trajectory") and "results identical" in lines
    lines, count = compare_results(RUN, _other(hashes={"dataset": "0" * 64}, lower=[0.1, 0.2000001]))
    assert count == 2  # the dataset's hash and the box's lower bound
    assert lines[0].startswith("first difference: dataset")
    assert "  /methods/hull/lower[1]: 0.2 -> 0.2000001" in lines


def test_compare_command_exit_codes(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "result.json").write_text(json.dumps(RUN))
    (tmp_path / "b.json").write_text(json.dumps(_other(hashes={"trajectory": "e" * 64})))
    (tmp_path / "c.json").write_text(json.dumps(_other()))
    runner = CliRunner()
    same = runner.invoke(app, ["compare", str(tmp_path / "a"), str(tmp_path / "c.json")])
    assert same.exit_code == 0, same.output
    assert "results identical" in same.output
    differ = runner.invoke(app, ["compare", str(tmp_path / "a" / "result.json"), str(tmp_path / "b.json")])
    assert differ.exit_code == 1
    assert "first difference: trajectory" in differ.output
    missing = runner.invoke(app, ["compare", str(tmp_path / "a"), str(tmp_path / "nowhere.json")])
    assert missing.exit_code == 2
