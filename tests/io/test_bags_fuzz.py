"""Damaged bags: bags of every storage (ROS 1, ROS 2 sqlite3, ROS 2 MCAP, and a slice of a real
ROS 1 recording when the shared data are present) mutated by bit flips, truncation and zeroed
byte ranges are read into arrays with a `BagReport`, or refused with `BagError`; nothing else
escapes, and no read takes longer than a few seconds.

``JAXTRACK_FUZZ_EXAMPLES`` sets the mutations per format (default 30; e.g. 500 for a long run).
"""

import os
import shutil
import signal
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from jaxtrack.io import bags  # noqa: E402

EXAMPLES = int(os.environ.get("JAXTRACK_FUZZ_EXAMPLES", "30"))
SECONDS = 10.0          # per mutated bag, all of its reads
T, B = 30, 24
DEMO = (Path(__file__).resolve().parents[3] / "shared" / "data" / "leg_tracker"
        / "demo_stationary_simple_environment.bag")
DEMO_SLICE = 200_000    # bytes of the real recording: ~90 scans, no index


def _records():
    rng = np.random.default_rng(0)
    times = 1.7e9 + 0.1 * np.arange(T)
    ranges = rng.uniform(0.05, 6.0, (T, B)).astype(np.float32)
    mask = ranges < 5.6
    laser = bags.LaserScans(times, np.where(mask, ranges, np.float32(5.6)),
                            bags.beam_angles(-1.2, 2.4 / (B - 1), B), mask, 0.02, 5.6,
                            np.ones(T, bool))
    pose = np.column_stack([rng.normal(size=(T, 2)), rng.uniform(-np.pi, np.pi, T)])
    odom = bags.Odometry(times + 0.05, pose, rng.normal(size=(T, 3)), np.ones(T, bool))
    return laser, odom


def _sources(root: Path) -> dict:
    """Intact bags, by format: (path, the file to mutate inside it, the topics to read)."""
    laser, odom = _records()
    out = {}
    for name, version, storage, extra in [("ros1", 1, "sqlite3", {"chunk_bytes": 2048}),
                                          ("ros1_lz4", 1, "sqlite3",
                                           {"chunk_bytes": 2048, "compression": "lz4"}),
                                          ("sqlite3", 2, "sqlite3", {}),
                                          ("mcap", 2, "mcap", {})]:
        p = root / (f"{name}.bag" if version == 1 else name)
        bags.write_bag(p, version, laser=laser, odometry=odom, storage=storage, **extra)
        f = p if version == 1 else next(x for x in p.iterdir() if x.suffix in (".db3", ".mcap"))
        out[name] = (p, f, ("/scan", "/odom"))
    if DEMO.exists():
        p = root / "demo_slice.bag"
        with open(DEMO, "rb") as fh:
            p.write_bytes(fh.read(DEMO_SLICE))
        out["demo_slice"] = (p, p, ("/scan",))
    return out


def mutate(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """One of: flip 1-8 random bits, cut the file, zero a byte range."""
    buf = bytearray(data)
    kind = rng.integers(3)
    if kind == 0:
        bits = rng.integers(0, 8 * len(buf), rng.integers(1, 9))
        for b in bits:
            buf[b // 8] ^= 1 << (b % 8)
        return bytes(buf), f"flip bits {sorted(int(b) for b in bits)}"
    if kind == 1:
        n = int(rng.integers(0, len(buf)))
        return bytes(buf[:n]), f"cut at {n}"
    a = int(rng.integers(0, len(buf)))
    n = int(rng.integers(1, min(4096, len(buf) - a) + 1))
    buf[a:a + n] = bytes(n)
    return bytes(buf), f"zero [{a}, {a + n})"


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


def read_all(path: Path, topics) -> tuple[str, str]:
    """Read every topic of a (damaged) bag, also onto a 10 Hz grid: ("report", ...) when each
    read gave arrays + a report or a BagError, ("error", ...) otherwise."""
    outcomes = []
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, SECONDS)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", bags.BagWarning)
            for topic in topics:
                read = bags.read_laser if topic == "/scan" else bags.read_odometry
                for rate in (None, 10.0):
                    try:
                        rec = read(path, topic, rate=rate)
                    except bags.BagError as err:
                        if path.name not in str(err):
                            return "error", f"{topic}: BagError not naming the file: {err}"
                        outcomes.append(("bagerror", str(err)))
                        continue
                    except _Timeout:
                        return "error", f"{topic}: no answer within {SECONDS} s"
                    except Exception as err:  # noqa: BLE001 - the property under test
                        return "error", f"{topic}: {type(err).__name__}: {err}"
                    if not isinstance(rec.report, bags.BagReport) or len(rec.times) == 0:
                        return "error", f"{topic}: no report or no rows"
                    outcomes.append(("read", rec.report.detail))
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    if all(k == "bagerror" for k, _ in outcomes):
        return "bagerror", outcomes[0][1]
    return "read", "; ".join(d for k, d in outcomes if d)


def fuzz(source, work: Path, examples: int, seed: int) -> dict:
    """Mutate ``source`` ``examples`` times; counts of outcomes and the failures."""
    path, target, topics = source
    original = target.read_bytes()
    rng = np.random.default_rng(seed)
    counts, failures, errors = {"read": 0, "bagerror": 0, "error": 0}, [], {}
    for i in range(examples):
        data, how = mutate(original, rng)
        case = work / f"case{i}"
        if path.is_dir():
            shutil.copytree(path, case)
            f = case / target.name
        else:
            case.mkdir()
            case = f = case / path.name
        f.write_bytes(data)
        kind, what = read_all(case, topics)
        counts[kind] += 1
        if kind == "error":
            failures.append(f"{how}: {what}")
        elif kind == "bagerror":   # by kind of message, the file's name left out
            key = what.replace(str(case), "BAG").split(";")[0][:90]
            errors[key] = errors.get(key, 0) + 1
        shutil.rmtree(case if case.is_dir() else case.parent)
    return {"counts": counts, "failures": failures, "errors": errors}


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    return _sources(tmp_path_factory.mktemp("fuzz"))


FORMATS = ["ros1", "ros1_lz4", "sqlite3", "mcap", "demo_slice"]


@pytest.mark.parametrize("fmt", FORMATS)
def test_mutated_bag_is_read_with_a_report_or_refused_with_bag_error(sources, tmp_path, fmt):
    if fmt not in sources:
        pytest.skip(f"{DEMO} is not present")
    t0 = time.perf_counter()
    result = fuzz(sources[fmt], tmp_path, EXAMPLES, seed=FORMATS.index(fmt))
    assert not result["failures"], "\n".join(result["failures"][:10])
    assert result["counts"]["read"] > 0
    assert time.perf_counter() - t0 < SECONDS * EXAMPLES


if __name__ == "__main__":  # a long run: python -m tests.io.test_bags_fuzz [examples]
    import sys
    import tempfile

    n = int(sys.argv[1]) if len(sys.argv) > 1 else 500
    with tempfile.TemporaryDirectory() as tmp:
        src = _sources(Path(tmp))
        for k, fmt in enumerate(FORMATS):
            if fmt not in src:
                continue
            t0 = time.perf_counter()
            r = fuzz(src[fmt], Path(tmp), n, seed=1000 + k)
            print(f"{fmt}: {n} cases, {r['counts']}, {time.perf_counter() - t0:.1f} s",
                  flush=True)
            for f in r["failures"]:
                print("   ", f)
            for e, c in sorted(r["errors"].items(), key=lambda x: -x[1]):
                print(f"    BagError x{c}: {e}")
