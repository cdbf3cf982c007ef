"""The tier rules of tests/conftest.py, run on a scratch suite with that conftest: a test's
tier is its folder, a file outside a tier folder or a marker against the folder is an error
at collection, and a unit test over its CPU budget fails, named in one line."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ("pytester",)

TESTS = Path(__file__).resolve().parents[1]


@pytest.fixture
def suite(pytester):
    """A scratch tests/ with our conftest (its CPU budget cut to 0.3 s) and helpers' path."""
    conftest = (TESTS / "conftest.py").read_text()
    assert "\nUNIT_CPU_BUDGET_S = 10.0\n" in conftest
    (pytester.path / "tests").mkdir()
    (pytester.path / "tests" / "conftest.py").write_text(conftest.replace("\nUNIT_CPU_BUDGET_S = 10.0\n",
                                                                          "\nUNIT_CPU_BUDGET_S = 0.3\n"))
    pytester.makepyprojecttoml(f'[tool.pytest.ini_options]\npythonpath = ["{TESTS}"]\naddopts = "--strict-markers"\n'
                               'markers = ["unit", "io", "sil", "firmware", "qemu", "slow"]\n')

    def add(path: str, text: str) -> None:
        p = pytester.path / "tests" / path
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text("import time\n\nimport pytest\n\n\n" + text)

    return add


def test_a_test_gets_its_folders_tier_and_strays_are_collection_errors(suite, pytester):
    suite("unit/test_a.py", "def test_plain():\n    pass\n\n\n@pytest.mark.unit\ndef test_marked_alike():\n    pass\n")
    suite("sil/test_b.py", "pytestmark = pytest.mark.slow\n\n\ndef test_sim():\n    pass\n")
    r = pytester.runpytest_subprocess("tests", "-m", "unit", "-p", "no:cacheprovider")
    assert r.ret == 0 and r.parseoutcomes() == {"passed": 2, "deselected": 1}
    r = pytester.runpytest_subprocess("tests", "-m", "sil and slow", "-p", "no:cacheprovider")
    assert r.ret == 0 and r.parseoutcomes() == {"passed": 1, "deselected": 2}

    suite("test_stray.py", "def test_loose():\n    pass\n")
    suite("io/test_c.py", "@pytest.mark.sil\ndef test_mismatch():\n    pass\n")
    r = pytester.runpytest_subprocess("tests", "-p", "no:cacheprovider")
    assert r.ret == pytest.ExitCode.USAGE_ERROR
    err = r.stderr.str()
    assert "tests/test_stray.py::test_loose: not in a tier folder" in err
    assert "tests/io/test_c.py::test_mismatch: marked sil in tests/io/" in err


def test_a_unit_test_over_its_cpu_budget_fails_named_in_one_line(suite, pytester):
    spin = "    end = time.process_time() + 0.6\n    while time.process_time() < end:\n        pass\n"
    suite("unit/test_spin.py", f"def test_spins():\n{spin}\n\ndef test_quick():\n    pass\n")
    suite("io/test_spin_io.py", f"def test_spins_too():\n{spin}")  # other tiers have no budget
    r = pytester.runpytest_subprocess("tests", "-p", "no:cacheprovider", "-rf")
    assert r.parseoutcomes() == {"failed": 1, "passed": 2}
    r.stdout.fnmatch_lines(["tests/unit/test_spin.py::test_spins: 0.* s of CPU in set-up and call, over the unit "
                            "tier's budget of 0.3 s (tests/conftest.py): make it smaller or move it to tests/sil"])
