"""Command line: argument handling and the section 5.5 table (no episode compile here)."""

import numpy as np
import pytest

from sims import cli


def _fake(rng, frames=10):
    active = np.arange(frames)[None] < 7
    return {"active": np.repeat(active, 4, 0), "pos_err": rng.uniform(0, 0.05, (4, frames)),
            "heading_err": rng.uniform(0, 8, (4, frames)), "success": np.ones(4),
            "frames_to_stop": np.full(4, 7.0), "final_pos_err": np.full(4, 0.03)}


def test_table_has_one_row_per_seed_task_and_a_total():
    rng = np.random.default_rng(0)
    table = cli.task_table([_fake(rng) for _ in range(15)], 10)
    lines = table.splitlines()
    assert lines[2].startswith("P1 -90") and lines[16].startswith("P3 +90")
    assert lines[18].startswith("all") and "100.0%" in lines[18]


def test_unknown_tracker_and_bad_counts_are_rejected(capsys):
    with pytest.raises(SystemExit):
        cli.main(["run", "humanoid-reach", "--tracker", "kcf"])
    assert "invalid choice: 'kcf'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["run", "humanoid-reach", "--planner", "herdt"])
    assert "invalid choice: 'herdt'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["run", "humanoid-reach", "--episodes", "0"])
    assert "must be positive" in capsys.readouterr().err


def test_humanoid_tunable_values_reach_the_run_and_bad_ones_are_rejected(capsys, monkeypatch):
    seen = {}
    monkeypatch.setattr(cli, "run_humanoid_reach", lambda *a, **kw: seen.update(kw))
    assert cli.main(["run", "humanoid-reach", "--lambda-x", "0.4", "--lambda-theta", "0.9",
                     "--position-noise", "0.041", "--temperature", "1.1", "--turn-prediction",
                     "--heading-gain", "0.3", "--walkers", "2", "--planner", "preview-qp",
                     "--objects", "3", "--unknown-objects"]) == 0
    assert seen == {"lambda_x": 0.4, "lambda_theta": 0.9, "position_noise": 0.041,
                    "temperature": 1.1, "turn_prediction": True, "heading_gain": 0.3,
                    "walkers": 2, "planner": "preview-qp", "objects": 3,
                    "static_background": False}
    assert cli.main(["run", "humanoid-reach"]) == 0
    assert seen["walkers"] == 0 and seen["planner"] == "dcm"
    assert seen["objects"] == 0 and seen["static_background"] is True
    assert seen["temperature"] is None and seen["lambda_x"] == 0.1
    assert seen["turn_prediction"] is False and seen["heading_gain"] == 0.5
    with pytest.raises(SystemExit):
        cli.main(["run", "humanoid-reach", "--heading-gain", "1.5"])
    assert "--heading-gain must be in (0, 1]" in capsys.readouterr().err
    for flag in ("--lambda-x", "--temperature"):
        with pytest.raises(SystemExit):
            cli.main(["run", "humanoid-reach", flag, "-1"])
        assert f"{flag} must be a finite positive number" in capsys.readouterr().err


def test_table_labels_a_subset_of_tasks_by_the_names_given():
    rng = np.random.default_rng(1)
    names = [cli.TASK_NAMES[i] for i in (3, 11)]
    lines = cli.task_table([_fake(rng) for _ in range(2)], 10, names=names).splitlines()
    assert lines[2].startswith("P1 +45") and lines[3].startswith("P3 -45")
    assert lines[5].startswith("all")
    # Without names, results are tasks 0, 1, ... in order.
    lines = cli.task_table([_fake(rng) for _ in range(2)], 10).splitlines()
    assert lines[2].startswith("P1 -90") and lines[3].startswith("P1 -45")
    with pytest.raises(ValueError, match="2 results and 1 names"):
        cli.task_table([_fake(rng) for _ in range(2)], 10, names=names[:1])


@pytest.mark.parametrize("argv, message", [
    (["run", "person-following", "--duration", "nan"], "--duration finite"),
    (["run", "person-following", "--batch-size", "-5"], "--batch-size must be positive"),
    (["run", "person-following", "--batch-size", "0"], "--batch-size must be positive"),
    (["run", "person-following", "--animate"], "--animate needs --out"),
    (["run", "humanoid-reach", "--resolution", "0", "0"], "--resolution must be at least"),
    (["run", "humanoid-reach", "--lambda-x", "nan"], "--lambda-x must be a finite"),
    (["demo", "filters", "--episodes", "0"], "must be positive"),
    (["run", "rgbd-people", "--episodes", "0"], "--episodes and --duration must be positive"),
    (["run", "rgbd-people", "--duration", "inf"], "--duration finite"),
    (["run", "rgbd-people", "--resolution", "4", "3"], "--resolution must be at least"),
    (["run", "rgbd-people", "--batch-size", "0"], "--batch-size must be positive"),
    (["train-hog", "--out", "x.npz", "--frames", "1"], "--frames must be at least 3"),
    (["train-hog", "--out", "x.npz", "--c", "-1"], "--c positive"),
    (["run", "service", "--experiment", "tv", "--episodes", "0"],
     "--episodes and --duration must be positive"),
    (["run", "service", "--experiment", "approach", "--interest", "2"],
     "--interest must be a number in [0, 1]"),
    (["run", "service", "--experiment", "approach", "--interest", "some"],
     "--interest must be a number in [0, 1]"),
    (["run", "service", "--experiment", "tv", "--animate"], "--animate needs --out"),
    (["run", "service", "--experiment", "tv", "--batch-size", "0"],
     "--batch-size must be positive"),
    (["run", "service", "--experiment", "dance"], "invalid choice"),
    (["run", "humanoid-routes", "--episodes", "0"], "--episodes and --particles must be >= 1"),
    (["run", "humanoid-routes", "--floor", "1,2"], "--floor must be three numbers"),
    (["run", "humanoid-routes", "--space", "lab"], "invalid choice"),
    (["run", "humanoid-routes", "--figure", "/proc/x/fig.png"], "cannot be written"),
])
def test_bad_run_arguments_exit_2_with_one_line_before_any_work(argv, message, capsys,
                                                                 monkeypatch):
    import sims.following.report as report

    monkeypatch.setattr(report, "run_person_following",
                        lambda *a, **k: pytest.fail("ran despite a bad argument"))
    monkeypatch.setattr(cli, "run_humanoid_reach",
                        lambda *a, **k: pytest.fail("ran despite a bad argument"))
    import sims.following.crowd_report as crowd_report

    for name in ("run_rgbd_people", "train_hog"):
        monkeypatch.setattr(crowd_report, name,
                            lambda *a, **k: pytest.fail("ran despite a bad argument"))
    import sims.service.report as service_report

    monkeypatch.setattr(service_report, "run_service",
                        lambda *a, **k: pytest.fail("ran despite a bad argument"))
    from sims.humanoid import routes

    monkeypatch.setattr(routes, "run", lambda *a, **k: pytest.fail("ran despite a bad argument"))
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_unwritable_out_and_bad_static_points_are_found_first(tmp_path, capsys, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setattr(cli, "run_humanoid_reach",
                        lambda *a, **k: pytest.fail("ran despite a bad argument"))
    for argv in (["run", "humanoid-reach", "--out", str(blocker / "out")],
                 ["run", "person-following", "--out", str(blocker / "out")]):
        with pytest.raises(SystemExit) as exc:
            cli.main(argv)
        assert exc.value.code == 2 and "not a writable directory" in capsys.readouterr().err
    bag = tmp_path / "x.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n")
    points = tmp_path / "points.txt"
    points.write_text("1 2 3\n4 5 6\n")
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--bag", str(bag), "--laser-topic", "/scan", "--static-points",
                  str(points), "--out", str(tmp_path / "o")])
    assert exc.value.code == 2 and "expected 2 columns" in capsys.readouterr().err


def test_rgbd_people_passes_its_arguments_and_names_the_ablations(monkeypatch, tmp_path):
    import sims.following.crowd_report as crowd_report

    seen = {}
    monkeypatch.setattr(crowd_report, "run_rgbd_people", lambda *a, **k: seen.update(args=a))
    assert cli.main(["run", "rgbd-people", "--episodes", "3", "--scenario", "obstacles",
                     "--resolution", "320", "240", "--ablations", "full", "no-sub-clustering",
                     "--out", str(tmp_path)]) == 0
    episodes, scenario, _, resolution, names = seen["args"][:5]
    assert (episodes, scenario, resolution) == (3, "obstacles", (320, 240))
    from sims.following import crowd
    assert names == ("full", "no sub-clustering") and all(n in crowd.ABLATIONS for n in names)


def test_service_approach_options_reach_the_run(monkeypatch):
    import sims.service.report as service_report

    seen = {}
    monkeypatch.setattr(service_report, "run_service", lambda *a, **k: seen.update(args=a, kw=k))
    assert cli.main(["run", "service", "--experiment", "approach", "--interest", "0.5",
                     "--heading-filter", "sustained", "--pan", "--reverse", "--episodes", "4",
                     "--settle", "200", "--still-at-end", "5", "--heading-frame", "map",
                     "--line-of-sight", "--replan-every", "10", "--cell", "0.2",
                     "--births", "any"]) == 0
    assert seen["args"][:2] == ("approach", 4) and seen["args"][5] == 0.5
    assert seen["kw"] == {"heading_filter": "sustained", "pan": True, "reverse": True,
                          "settle_iterations": 200, "still_at_end": 5.0, "heading_frame": "map",
                          "line_of_sight": True, "replan_every": 10, "cell": 0.2,
                          "corroborated_births": False}
    assert cli.main(["run", "service", "--experiment", "approach"]) == 0
    assert seen["kw"] == {"heading_filter": None, "pan": False, "reverse": False,
                          "settle_iterations": 0, "still_at_end": 0.0, "heading_frame": "odom",
                          "line_of_sight": False, "replan_every": None, "cell": 0.1,
                          "corroborated_births": True}
    for bad in (["--settle", "-1"], ["--still-at-end", "90"], ["--replan-every", "0"],
                ["--cell", "0.01"], ["--births", "some"]):
        with pytest.raises(SystemExit):
            cli.main(["run", "service", "--experiment", "approach"] + bad)


def test_humanoid_routes_is_a_run_scene_with_its_own_help(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", "humanoid-routes", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: jaxtrack run humanoid-routes") and "--temperature" in out
