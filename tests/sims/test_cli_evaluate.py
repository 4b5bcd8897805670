"""``jaxtrack evaluate``: the MOTChallenge summary of py-motmetrics' TUD files, its CSV and JSON,
and one-line errors with exit code 2 for every user error."""

import json
import os

import motmetrics as mm
import pytest

from sims import cli

DATA = os.path.join(os.path.dirname(mm.__file__), "data")


def _files(name):
    return os.path.join(DATA, name, "gt.txt"), os.path.join(DATA, name, "test.txt")


def test_evaluate_prints_the_summary_and_writes_csv_and_json(tmp_path, capsys):
    (g1, t1), (g2, t2) = _files("TUD-Campus"), _files("TUD-Stadtmitte")
    out = tmp_path / "out"
    assert cli.main(["evaluate", "--gt", g1, g2, "--tracks", t1, t2, "--out", str(out)]) == 0
    text = capsys.readouterr().out.splitlines()
    assert "image plane" in text[0] and "1 - IoU" in text[0]
    assert text[1].split()[:2] == ["IDF1", "IDP"] and text[1].split()[-1] == "HOTA"
    assert text[2].split()[:4] == ["TUD-Campus", "55.8%", "73.0%", "45.1%"]
    assert text[4].split()[:2] == ["OVERALL", "62.4%"]
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary) == ["TUD-Campus", "TUD-Stadtmitte", "OVERALL"]
    assert summary["OVERALL"]["num_misses"] == 602
    assert (out / "summary.csv").read_text().splitlines()[0].startswith("name,idf1,idp")


def test_one_sequence_has_no_overall_row_and_takes_a_name(capsys):
    g, t = _files("TUD-Campus")
    assert cli.main(["evaluate", "--gt", g, "--tracks", t, "--names", "campus"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3 and lines[2].startswith("campus")


@pytest.mark.parametrize("extra, message", [
    (["--threshold", "-1"], "--threshold must be a finite positive"),
    (["--threshold", "nan"], "--threshold must be a finite positive"),
    (["--zero-distance", "0"], "--zero-distance must be a finite positive"),
    (["--names", "a", "b"], "--names must name every sequence"),
    (["--format", "kitti"], "invalid choice"),
])
def test_bad_arguments_exit_2_with_one_line(extra, message, capsys):
    g, t = _files("TUD-Campus")
    with pytest.raises(SystemExit) as exc:
        cli.main(["evaluate", "--gt", g, "--tracks", t] + extra)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_file_errors_exit_2_with_one_line(tmp_path, capsys):
    g, t = _files("TUD-Campus")
    cases = [(["--gt", g, "--tracks", str(tmp_path / "nope.txt")], "no such file"),
             (["--gt", g, g, "--tracks", t], "as many files")]
    ground = tmp_path / "ground.txt"
    ground.write_text("1 1 0.5 0.5\n")
    cases.append((["--gt", g, "--tracks", str(ground)], "without the image boxes"))
    bad = tmp_path / "bad.txt"
    bad.write_text("1 1 0.5\n")
    cases.append((["--gt", str(bad), "--tracks", str(ground)], "cannot tell the format"))
    blocker = tmp_path / "file"
    blocker.write_text("")
    cases.append((["--gt", g, "--tracks", t, "--out", str(blocker / "sub")], "not a writable"))
    for argv, message in cases:
        with pytest.raises(SystemExit) as exc:
            cli.main(["evaluate"] + argv)
        assert exc.value.code == 2, argv
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) <= 3, (argv, err)


def test_target_only_counts_no_false_positive_away_from_the_labelled_person(tmp_path, capsys):
    import numpy as np

    gt = np.array([(t, 1, 0.5 * t, 0.0) for t in range(1, 6)])
    tracks = np.array([(t, 4, 0.5 * t + 0.05, 0.0) for t in range(1, 6)]
                      + [(t, 9, 3.0, 3.0) for t in range(1, 6)])
    np.savetxt(tmp_path / "gt.txt", gt)
    np.savetxt(tmp_path / "tracks.txt", tracks)
    argv = ["evaluate", "--gt", str(tmp_path / "gt.txt"), "--tracks",
            str(tmp_path / "tracks.txt"), "--format", "plain", "--out", str(tmp_path / "o")]
    assert cli.main(argv) == 0
    rows = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert rows[next(iter(rows))]["num_false_positives"] == 5
    capsys.readouterr()
    assert cli.main(argv + ["--target-only"]) == 0
    rows = json.loads((tmp_path / "o" / "summary.json").read_text())
    row = rows[next(iter(rows))]
    assert row["num_false_positives"] == 0 and row["num_misses"] == 0 and row["mota"] == 1.0
