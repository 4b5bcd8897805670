"""``jaxtrack demo``: the dispatch, the scene demo at tiny sizes, the filter demo, the quiet MJX
import and the person-following table of a single-person estimator."""

import io
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from sims import cli
from sims import demo as scene_demo
from sims.following import report


def test_demo_runs_both_scenes_by_default_and_filters_on_request(monkeypatch, capsys):
    seen = []
    monkeypatch.setattr(scene_demo, "run", lambda which, **kw: seen.append((which, kw)))
    assert cli.main(["demo"]) == 0
    assert cli.main(["demo", "following", "--seed", "3"]) == 0
    assert seen == [("all", {"seed": 0}), ("following", {"seed": 3})]
    with pytest.raises(SystemExit):
        cli.main(["demo", "--episodes", "8"])
    assert "apply to `jaxtrack demo filters`" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["demo", "everything"])
    assert "invalid choice: 'everything'" in capsys.readouterr().err
    assert seen == [("all", {"seed": 0}), ("following", {"seed": 3})]


def test_demo_filters_prints_the_filter_table(capsys):
    assert cli.main(["demo", "filters", "--episodes", "8", "--steps", "20"]) == 0
    out = capsys.readouterr().out
    assert "jaxtrack filter demo: 8 episodes x 20 steps" in out
    for row in ("KF   (position detections)", "EKF  (range-bearing)", "UKF  (range-bearing)",
                "raw position detections"):
        assert row in out


_HUMANOID = scene_demo.HumanoidSize(episodes=1, frames=4, resolution=(32, 24), particles=8)
# the shapes of tests/sims/following/test_episode.py's command test
_FOLLOWING = scene_demo.FollowingSize(episodes=2, duration=1.0, people=2, estimator="kf",
                                      batch_size=2)


def _demo(which):
    stream = io.StringIO()
    out = scene_demo.run(which, _HUMANOID, _FOLLOWING, stream=stream, progress=False)
    text = stream.getvalue()
    return out, text, [line for line in text.splitlines() if line.startswith("== ")]


def test_scene_demo_humanoid_prints_its_header_and_table():
    out, text, headers = _demo("humanoid")
    assert len(headers) == 1
    assert "15 tasks x 1 episodes x 4 frames" in headers[0] and "32x24" in headers[0]
    assert "P3 +90" in text and "frames to stop" in text
    assert len(out["humanoid"]["metrics"]) == 15 and "following" not in out
    assert "demo finished in" in text


def test_scene_demo_all_runs_both_scenes_with_a_header_each(monkeypatch):
    # the humanoid scene runs for real above, the person-following one in
    # tests/sims/following/test_episode.py (the command test, the same sizes); here, the order,
    # the headers and what reaches each scene
    import sims.cli
    import sims.following.report

    calls = []

    def fake(name):
        def run(*args, stream, **kw):
            calls.append((name, args, kw))
            print(f"{name} table", file=stream)
            return {"metrics": name}
        return run

    monkeypatch.setattr(sims.cli, "run_humanoid_reach", fake("humanoid"))
    monkeypatch.setattr(sims.following.report, "run_person_following", fake("following"))
    out, text, headers = _demo("all")
    assert [c[0] for c in calls] == ["humanoid", "following"]
    assert calls[0][1] == (1, "pf") and calls[0][2]["frames"] == 4 \
        and calls[0][2]["resolution"] == (32, 24) and calls[0][2]["particles"] == 8
    assert calls[1][1] == (2, "kf", "A", 2) and calls[1][2]["duration"] == 1.0 \
        and calls[1][2]["batch_size"] == 2 and calls[1][2]["layout"] == "shop"
    assert "2 episodes x 1 s in the shop, kf estimator" in headers[1]
    assert len(headers) == 2 and "humanoid reach" in headers[0] \
        and "person following" in headers[1]
    lines = text.splitlines()
    assert lines.index("humanoid table") < lines.index(headers[1])
    assert out["humanoid"] == {"metrics": "humanoid"} and "seconds" in out


def test_scene_demo_rejects_an_unknown_scene():
    with pytest.raises(ValueError, match="which must be"):
        scene_demo.run("filters")


def test_the_warp_backend_notices_are_not_printed_by_the_command():
    quiet = textwrap.dedent("""
        import sys
        from sims import cli, demo
        demo.run = lambda which, **kw: print("ran", which)
        cli.main(["demo"])
        print("mjx imported:", "mujoco.mjx" in sys.modules)
    """)
    res = subprocess.run([sys.executable, "-c", quiet], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.splitlines() == ["ran all", "mjx imported: True"]
    assert "Failed to import" not in res.stderr
    # Without the command line's import, mujoco.mjx does print them when Warp is absent.
    raw = subprocess.run([sys.executable, "-c", "import mujoco.mjx, mujoco.mjx.warp as w; "
                          "print('warp', w.WARP_INSTALLED)"], capture_output=True, text=True)
    if "warp False" in raw.stdout:
        assert "Failed to import warp" in raw.stdout


def _single_person_metrics(n=5):
    # What a person-following episode returns for a single-person estimator (pf, kf, truth):
    # CLEAR MOT and the identity metrics are not scored, so NaN and -1.
    rng = np.random.default_rng(0)
    return {"following_rms": rng.uniform(0.2, 1.0, n), "lost_fraction": rng.uniform(0, 0.2, n),
            "user_switches": rng.integers(0, 4, n), "mota": np.full(n, np.nan),
            "motp": np.full(n, np.nan), "mot_switches": np.full(n, -1),
            "idf1": np.full(n, np.nan), "hota": np.full(n, np.nan),
            "near_fraction": rng.uniform(0, 0.1, n), "stop_fraction": np.zeros(n)}


def test_single_person_table_has_no_mot_rows_and_no_nan():
    table = report.metrics_table(_single_person_metrics(), "pf", multi_target=False)
    for name in ("MOTA", "MOTP", "MOT id switches", "IDF1", "HOTA"):
        assert name not in table
    assert "nan" not in table and "-1" not in table
    assert "following RMS error [m]" in table and "user id switches" in table


def test_multi_target_table_has_the_mot_rows():
    m = _single_person_metrics() | {"mota": np.full(5, 0.8), "motp": np.full(5, 0.05),
                                    "mot_switches": np.array([0, 1, 0, 2, 0]),
                                    "idf1": np.full(5, 0.7), "hota": np.full(5, 0.6)}
    table = report.metrics_table(m, "jpda", multi_target=True)
    assert "MOTA" in table and "80.00%" in table and "MOT id switches" in table
    assert "IDF1" in table and "HOTA" in table
    # Multi-target metrics are not shown for a single-person estimator even if present.
    assert "MOTA" not in report.metrics_table(m, "pf", multi_target=False)
