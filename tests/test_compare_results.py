"""benchmarks/compare_results.py: two checkouts of the same code compare equal; a changed value, another model
file or a missing key shows."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("compare_results", ROOT / "benchmarks" / "compare_results.py")
compare_results = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(compare_results)


def test_differences_ignore_timings_and_the_checkout_but_not_results():
    diff = compare_results.differences
    before = {"model": "/a/wt/speed/models/h4.xml", "timings": {"run": 1.0}, "box": [0.1, 0.2], "seconds": 3}
    after = {"model": "/b/main/models/h4.xml", "timings": {"run": 2.0}, "box": [0.1, 0.2], "seconds": 4}
    assert diff(before, after) == []
    assert diff(before, {**after, "box": [0.1, 0.2000000001]}) == ["/box[1]: 0.2 -> 0.2000000001"]
    assert diff(before, {**after, "model": "/b/main/models/other.xml"}) == [
        "/model: 'models/h4.xml' -> 'models/other.xml'"]
    assert diff(before, {k: v for k, v in after.items() if k != "box"}) == ["/box: only before"]
