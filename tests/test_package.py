"""Package-level behaviour: import hygiene, README examples, the demo command."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_import_jaxtrack_does_not_import_mujoco():
    code = ("import sys, jaxtrack, jaxtrack.filters, jaxtrack.models, jaxtrack.demo, "
            "jaxtrack.plotting, sims.cli; "
            "bad = [m for m in sys.modules if m.split('.')[0] in ('mujoco', 'mujoco_mjx')]; "
            "print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


README_EXAMPLES = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)


def test_readme_has_python_examples():
    assert README_EXAMPLES, "README has no python example"


@pytest.mark.parametrize("block", README_EXAMPLES,
                         ids=[f"example{i}" for i in range(len(README_EXAMPLES))])
def test_readme_usage_example_runs(block):
    exec(compile(block, "README.md", "exec"), {})


def test_readme_quickstart_has_exactly_two_commands_and_ci_runs_the_second():
    text = (ROOT / "README.md").read_text()
    quick = text.split("## Quickstart", 1)[1].split("```bash\n", 1)[1].split("```", 1)[0]
    lines = [ln for ln in quick.splitlines() if ln.strip()]
    assert len(lines) == 2
    assert "jaxtrack demo" in lines[0] and "pytest" in lines[1]
    ci = (ROOT / ".ci" / "run").read_text()
    assert ".venv/bin/python -m pytest" in ci


def jaxtrack_command():
    """The installed console script, or the module it points to."""
    script = Path(sys.executable).parent / "jaxtrack"
    return [str(script)] if script.exists() else [sys.executable, "-m", "sims.cli"]


def test_demo_command_prints_a_results_table_with_consistent_filters():
    out = subprocess.run(jaxtrack_command() + ["demo", "filters", "--episodes", "8", "--steps",
                                               "30"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    rows = {line.split("  ")[0].strip(): line for line in out.stdout.splitlines()}
    kf = [r for k, r in rows.items() if k.startswith("KF")]
    assert kf, out.stdout
    rmse_kf = float(kf[0].split()[-2])
    raw = [r for k, r in rows.items() if k.startswith("raw")]
    rmse_raw = float(raw[0].split()[-1])
    # Filtering must beat the raw detections it is given.
    assert rmse_kf < rmse_raw
    assert "episodes/s" in out.stdout


def test_cli_rejects_bad_arguments():
    out = subprocess.run(jaxtrack_command() + ["demo", "filters", "--episodes", "0"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode != 0 and "positive" in out.stderr
