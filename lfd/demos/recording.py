"""Recordings as people make them: the clean-up of raw demos read from files and bags.

Each demo's raw arrays pass, in this order, the steps of ``CLEAN_STEPS`` asked for (docs/recordings.md
states the rules and why):

1. ``gaps``: a time step over ``GAP_FACTOR`` median steps is cut when the arm barely moved across it,
   filled by cubic Hermite interpolation when it moved on as the velocities beside it carry it and
   the gap is at most ``MAX_GAP_S``, else refused;
2. ``noise``: positions and orientations smoothed (cubic Savitzky-Golay) when the noise estimated from
   their fourth differences would put more than ``NOISE_TRIGGER`` of the peak speed into the velocities;
3. ``still``: standing still at the start (end) for ``START_STILL_S`` (``END_STILL_S``) or more is
   trimmed to ``STILL_MARGIN_S``. Standing still: the position, averaged over ``STILL_AVERAGE``
   samples, stays within ``STILL_NOISE_K`` of its noise deviations of one point and does not drift
   (its line rises by at most ``STILL_DRIFT_K`` of its noise deviations), each plus ``STILL_FLOOR`` of
   the extent; the noise of each coordinate is that of the samples as recorded, before step 2;
4. ``pauses``: standing still inside the demo for ``PAUSE_S`` or more, between real moves, is cut to
   ``STILL_MARGIN_S`` and later times are moved back.

Then demos of different lengths are resampled to one, and ends spread beyond ``GOAL_TOLERANCE`` are
noted. Each thing done is one note line, which ends with the share of the demo's duration when a step
removed, filled or moved more than ``LOUD_SHARE`` of it (``loud_note``: said even when quiet); what
cannot be mended is a ``DemoError`` of one line. A demo that needs nothing, or whose steps are turned
off, passes through bit for bit. A turn of one radian weighs as ``ROTATION_LENGTH`` metres. The
shipped sets are never cleaned.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Callable, Iterable
from functools import lru_cache

import numpy as np

from lfd.demos.demoset import GOAL_ANGLE_TOLERANCE, GOAL_TOLERANCE, MIN_SAMPLES, DemoSet, check_demo, resample
from lfd.demos.smoothing import VELOCITY_ORDER, VELOCITY_WINDOW, savgol, savgol_coefficients
from lfd.errors import ConfigError, DemoError
from lfd.rotations import (
    ROTATION_LENGTH,
    continuous,
    from_rotation_vectors,
    geodesic_angle,
    mean_quaternion,
    quaternion_matrices,
    rotation_vectors,
    slerp,
)

CLEAN_STEPS: tuple[str, ...] = ("gaps", "noise", "still", "pauses")   # the steps, in their order
GAP_FACTOR = 3.0        # a time step longer than this many median steps is a gap
MAX_GAP_S = 0.25        # s: the longest gap that is interpolated while the arm moves across it
GAP_SIDE_S = 0.1        # s: the velocity at a gap's edge is that of a parabola fitted over this time
GAP_CONTINUITY = 0.25   # a gap's jump may differ from what the motion carries by this fraction of it
NOISE_TRIGGER = 0.03    # smooth when the velocity noise exceeds this fraction of the peak speed
NOISE_TARGET = 0.01     # the smoothing window is the shortest that brings it below this fraction
SMOOTH_MAX_S = 0.5      # s: the longest smoothing window
STILL_WINDOW_S = 0.5    # s: the peak speed is that of a line fitted over this time
STILL_AVERAGE = 5       # samples: the position judged still is the mean of a sample and two on each side
STILL_NOISE_K = 5.0     # still: each such mean within this many of its noise deviations of one point,
STILL_DRIFT_K = 3.0     # and the rise of its least-squares line within this many of its noise deviations,
STILL_FLOOR = 1e-6      # plus this fraction of the demo's extent (all that is left of a noiseless recording)
START_STILL_S = 0.3     # s: the shortest still stretch trimmed at the start
END_STILL_S = 1.5       # s: the shortest still stretch trimmed at the end (a creep into the goal is kept)
PAUSE_S = 0.5           # s: the shortest still stretch cut inside the demo (a pause)
STILL_MIN_SAMPLES = 10  # a still stretch holds at least this many samples (fewer cannot tell a rest from noise)
STILL_MARGIN_S = 0.1    # s: what is kept of a trimmed or cut still stretch
LOUD_SHARE = 0.05       # a step that removes, fills or moves more of a demo's duration says so when quiet
_SIDE_SAMPLES = 2       # the speed's line spans at least this many samples on each side
_NOISE_K = 4.0          # a gap's jump may exceed the motion by this many noise deviations per coordinate
_MAD = 0.6744897501960817   # the median absolute deviation of a standard normal distribution


def recorded_set(ts: list[np.ndarray], xs: list[np.ndarray], qs: list[np.ndarray] | None, name: str,
                 clean: bool | str | Iterable[str] = True) -> DemoSet:
    """The DemoSet of raw recordings, cleaned up, with its notes.

    Parameters
    ----------
    ts : list of N arrays, shape (T_i,)
        Each demo's times [s], strictly increasing.
    xs : list of N arrays, shape (T_i, d)
        Each demo's positions.
    qs : list of N arrays, shape (T_i, 4), or None
        Each demo's orientations (w, x, y, z), for poses.
    name : str
        The set's name (the spec), for the notes and the messages.
    clean : bool, str or iterable of str
        The clean-up steps to run (``clean_steps``: True all, False none, or names such as "gaps,noise";
        an unknown one is a ConfigError). Demos of different lengths are resampled whatever it says.

    Returns
    -------
    DemoSet
        t (N, T), x (N, T, d), q (N, T, 4) or None, ``notes`` saying what was done, one line each.
    """
    steps = clean_steps(clean)
    cleaned = [clean_demo(t, x, None if qs is None else qs[i], name, i, steps) for i, (t, x) in enumerate(zip(ts, xs))]
    notes = [note for *_, demo_notes in cleaned for note in demo_notes]
    if len({len(c[0]) for c in cleaned}) > 1:
        notes.append(_resample_note(cleaned, name))
    t, x, q = resample([c[0] for c in cleaned], [c[1] for c in cleaned],
                       None if qs is None else [c[2] for c in cleaned if c[2] is not None], name)
    spread = _spread_note(x[:, -1], x, None if q is None else q[:, -1], name)
    return DemoSet(t, x, name=name, q=q, notes=(*notes, *([spread] if spread else [])))


def clean_steps(clean: bool | str | Iterable[str] = True) -> frozenset[str]:
    """The subset of ``CLEAN_STEPS`` that ``clean`` asks for: True all, False none, a string of names
    separated by commas (or "all", "none"), or names; a name not in ``CLEAN_STEPS`` is a ConfigError."""
    if isinstance(clean, (bool, np.bool_)):
        return frozenset(CLEAN_STEPS) if clean else frozenset()
    words = [w.strip() for w in clean.split(",")] if isinstance(clean, str) else [str(w) for w in clean]
    if words in (["all"], ["none"]):
        return frozenset(CLEAN_STEPS) if words == ["all"] else frozenset()
    unknown = [w for w in words if w not in CLEAN_STEPS]
    if unknown:
        raise ConfigError(f"unknown clean-up step {unknown[0]!r}; the steps are {', '.join(CLEAN_STEPS)} "
                          "(or all, none)")
    return frozenset(words)


_LOUD = re.compile(r"; [0-9.]+% of its duration (removed|filled in)$")


def loud_note(note: str) -> bool:
    """Whether a note is that of a clean-up step that removed, filled or moved more than ``LOUD_SHARE``
    of a demo's duration (such a note ends with that share): one a quiet command still says."""
    return _LOUD.search(note) is not None


def _share(seconds: float, duration: float, what: str = "removed") -> str:
    """'; 12% of its duration removed' when ``seconds`` exceed ``LOUD_SHARE`` of ``duration``, else ''."""
    if not seconds > LOUD_SHARE * duration:
        return ""
    share = 100.0 * seconds / duration
    return f"; {share:.0f}% of its duration {what}" if share >= 9.5 else f"; {share:.1f}% of its duration {what}"


def clean_demo(t: np.ndarray, x: np.ndarray, q: np.ndarray | None, name: str, index: int,
               steps: frozenset[str] = frozenset(CLEAN_STEPS)
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[str]]:
    """One raw demo cleaned up: gaps, noise, standing still, pauses (the module's rules, in order).

    Parameters
    ----------
    t, x, q, name, index
        As ``lfd.demos.demoset.check_demo``'s: times (T,) [s], positions (T, d), orientations
        (T, 4) (w, x, y, z) or None, and the set's name and the demo's index for the notes.
    steps : frozenset of str
        The steps to run (``clean_steps``); the others do nothing.

    Returns
    -------
    t : array, shape (T',)
    x : array, shape (T', d)
    q : array, shape (T', 4), or None
        The cleaned demo: the input arrays themselves when nothing was done.
    notes : list of str
        One line per thing done, ``<name>: demo <index>: ...``.

    Raises
    ------
    DemoError
        What a ``DemoSet`` refuses, a gap that cannot be mended, a demo that never leaves its noise, or
        too few samples left.
    """
    check_demo(t, x, q, name, index)
    unit = None if q is None else continuous(q / np.linalg.norm(q, axis=1)[:, None])
    notes: list[str] = []
    where = f"{name}: demo {index}"
    duration = float(t[-1] - t[0])
    tc, xc, qc = t, x, unit
    with np.errstate(over="ignore", invalid="ignore"):    # huge but finite values: nothing is done to them
        if "gaps" in steps:
            tc, xc, qc = _gaps(t, x, unit, where, notes, duration)
        recorded = _coordinates(xc, qc)                    # the samples as recorded, gaps mended
        if "noise" in steps:
            tc, xc, qc = _noise(tc, xc, qc, where, notes)
        if steps & {"still", "pauses"}:
            sigma = _noise_deviations(_coordinates(x, unit))
            tc, xc, qc = _stillness(tc, xc, qc, recorded, sigma, steps, where, notes, duration)
    if tc is t and xc is x and qc is unit:
        return t, x, q, notes                                  # nothing done: the raw arrays, bit for bit
    if len(tc) < MIN_SAMPLES:
        raise DemoError(f"{where} has {len(tc)} samples left after the clean-up, at least {MIN_SAMPLES} are "
                        "needed; record it at a higher rate")
    return tc, xc, qc, notes


# ---------------------------------------------------------------- measures

def _coordinates(x: np.ndarray, q: np.ndarray | None) -> np.ndarray:
    """The demo as points y (T, d) or (T, d + 3): positions, and for poses ``ROTATION_LENGTH`` times
    the rotation vectors from the final orientation, so that a turn weighs as in the pose chart."""
    if q is None:
        return x
    return np.concatenate([x, ROTATION_LENGTH * rotation_vectors(q, q[-1])], axis=1)


def _noise_deviation(y: np.ndarray) -> float:
    """The standard deviation of white noise on the samples y (T, d), pooled over coordinates: the
    median absolute fourth difference over that of noise alone (sqrt(70) sigma times ``_MAD``); a smooth
    motion's own fourth differences are far smaller at recording rates. 0 below 5 samples."""
    if len(y) < 5:
        return 0.0
    fourth = np.diff(y, n=4, axis=0)
    return float(np.median(np.abs(fourth)) / (_MAD * np.sqrt(70.0)))


def _noise_deviations(y: np.ndarray) -> np.ndarray:
    """The noise deviation of each coordinate of y (T, d), shape (d,): ``_noise_deviation`` of each
    column on its own. 0 below 5 samples."""
    if len(y) < 5:
        return np.zeros(y.shape[1])
    return np.median(np.abs(np.diff(y, n=4, axis=0)), axis=0) / (_MAD * np.sqrt(70.0))


@lru_cache(maxsize=256)
def _velocity_noise_gain(window: int) -> float:
    """The standard deviation of a demo's velocity (``smoothed_velocity``) per unit of white position
    noise and of time step, after smoothing positions over ``window`` samples (1: not smoothed)."""
    kernel = savgol_coefficients(window, VELOCITY_ORDER) if window > 1 else np.ones(1)
    kernel = np.convolve(kernel, savgol_coefficients(VELOCITY_WINDOW, VELOCITY_ORDER))
    return float(np.linalg.norm(np.convolve(kernel, [0.5, 0.0, -0.5])))


def _edge_velocity(t: np.ndarray, y: np.ndarray, edge: float) -> np.ndarray:
    """dy/dt (d,) at time ``edge`` of the least-squares parabola through y (K, d) at times t (K,) (a line
    below 4 samples, 0 below 2): the velocity at the edge of a gap, from the samples beside it."""
    if len(t) < 2:
        return np.zeros(y.shape[1])
    return np.polyfit(t - edge, y, 2 if len(t) >= 4 else 1)[-2]


def _length(value: float, metres: bool) -> str:
    """A length for a note: centimetres or millimetres for poses (metres), else in the demos' units."""
    if not metres:
        return f"{value:.2g}"
    return f"{value * 100:.3g} cm" if value >= 0.01 else f"{value * 1000:.2g} mm"


# ---------------------------------------------------------------- 1. gaps

def _gaps(t: np.ndarray, x: np.ndarray, q: np.ndarray | None, where: str, notes: list[str], duration: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Mend the gaps of one demo: steps over ``GAP_FACTOR`` median steps h. Beside a gap of length
    Delta, v_b and v_a are the velocities of y at its edges (parabolas fitted over ``GAP_SIDE_S``),
    v the larger speed, a the noise allowance (``_NOISE_K`` deviations per coordinate of both samples).
    If the jump |y_a - y_b| <= 2 v h + a, the arm barely moved across it (a pause the recorder
    missed): the gap is cut and later times are moved back. Else if the jump is what the motion
    carries, |y_a - y_b - (v_b + v_a) Delta / 2| <= ``GAP_CONTINUITY`` v Delta + a, and
    Delta <= ``MAX_GAP_S``, it is filled at the step h (positions by cubic Hermite interpolation,
    orientations by Slerp). Anything else is a ``DemoError``. ``duration`` [s] is the demo's, for the
    share of it that the notes give (``_share``)."""
    steps = np.diff(t)
    h = float(np.median(steps))
    gaps = np.flatnonzero(steps > GAP_FACTOR * h)
    if not len(gaps):
        return t, x, q
    y = _coordinates(x, q)
    starts, stops = np.r_[0, gaps + 1], np.r_[gaps + 1, len(t)]
    sigma = float(np.median([_noise_deviation(y[a:b]) for a, b in zip(starts, stops)]))
    allowance = _NOISE_K * np.sqrt(2.0 * y.shape[1]) * sigma
    tp, xp, qp = [t[:stops[0]]], [x[:stops[0]]], [] if q is None else [q[:stops[0]]]
    shift, cut, filled, fill_s = 0.0, [], [], 0.0
    for g, k in enumerate(gaps):
        before, after = np.arange(starts[g], k + 1), np.arange(k + 1, stops[g + 1])
        before, after = before[t[before] >= t[k] - GAP_SIDE_S], after[t[after] <= t[k + 1] + GAP_SIDE_S]
        vb, va = _edge_velocity(t[before], y[before], t[k]), _edge_velocity(t[after], y[after], t[k + 1])
        speed = max(float(np.linalg.norm(vb)), float(np.linalg.norm(va)))
        delta, at = float(t[k + 1] - t[k]), float(t[k] - t[0])
        jump = y[k + 1] - y[k]
        off = float(np.linalg.norm(jump - 0.5 * (vb + va) * delta))       # what the motion does not explain
        carried = off <= GAP_CONTINUITY * speed * delta + allowance
        if float(np.linalg.norm(jump)) <= 2.0 * speed * h + allowance:   # a pause without samples: cut
            shift += delta - h
            cut.append(f"{delta:.2g} s at {at:.3g} s")
        elif carried and delta <= min(MAX_GAP_S, h * len(t)):     # never more samples filled than recorded
            m = max(2, int(round(delta / h)))
            s = np.arange(1, m)[:, None] / m
            vxb, vxa = vb[:x.shape[1]], va[:x.shape[1]]
            h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
            tp.append(t[k] + delta * s[:, 0] - shift)
            xp.append(h00 * x[k] + h10 * delta * vxb + h01 * x[k + 1] + h11 * delta * vxa)
            if q is not None:
                qp.append(slerp(t[k:k + 2], q[k:k + 2], t[k] + delta * s[:, 0]))
            filled.append(f"{delta:.2g} s at {at:.3g} s")
            fill_s += delta
        elif carried:
            raise DemoError(f"{where} has a {delta:.2g} s gap in its time stamps at {at:.3g} s while it moves, "
                            f"longer than the {MAX_GAP_S:g} s that is interpolated; record it again, or split "
                            "it there into two demos")
        else:
            raise DemoError(f"{where} jumps {_length(off, q is not None)} across a {delta:.2g} s gap in its "
                            f"time stamps at {at:.3g} s, beyond what its speed carries; record it again, or "
                            "split it there into two demos")
        tp.append(t[k + 1:stops[g + 1]] - shift)
        xp.append(x[k + 1:stops[g + 1]])
        if q is not None:
            qp.append(q[k + 1:stops[g + 1]])
    if filled:
        notes.append(f"{where}: interpolated {_listed(filled, 'gap')} in its time stamps "
                     f"(the motion runs on across {'them' if len(filled) > 1 else 'it'})"
                     + _share(fill_s, duration, "filled in"))
    if cut:
        notes.append(f"{where}: cut {_listed(cut, 'gap')} in its time stamps, across which it barely "
                     "moved; later times moved back" + _share(shift, duration))
    return np.concatenate(tp), np.concatenate(xp), None if q is None else continuous(np.concatenate(qp))


def _listed(items: list[str], what: str) -> str:
    """'a 0.2 s gap at 1.5 s' or 'gaps of 0.2 s at 1.5 s and 0.3 s at 2 s'."""
    if len(items) == 1:
        return f"a {items[0].replace(' at ', f' {what} at ', 1)}"
    return f"{what}s of {_and(items)}"


def _and(items: list[str]) -> str:
    """'a', 'a and b', 'a, b and c'."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"


# ---------------------------------------------------------------- 2. noise

def _noise(t: np.ndarray, x: np.ndarray, q: np.ndarray | None, where: str, notes: list[str]
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Smooth one demo when its noise would make its velocities noisy: with sigma the noise deviation
    of y (``_noise_deviation``), h the median step, g(w) the velocity noise gain after smoothing over
    w samples and the peak speed that of ``_line_speed`` (which noise hardly raises), smooth when
    g(1) sigma / h > ``NOISE_TRIGGER`` times the peak speed, over the shortest odd
    w with g(w) sigma / h <= ``NOISE_TARGET`` times it (at most ``SMOOTH_MAX_S``): positions, and the
    rotation vectors from the final orientation, each by a cubic Savitzky-Golay filter."""
    y = _coordinates(x, q)
    sigma = _noise_deviation(y)
    h = float(np.median(np.diff(t)))
    peak = float(np.max(_line_speed(t, y)))
    if not sigma > 0 or not peak > 0 or _velocity_noise_gain(1) * sigma / h <= NOISE_TRIGGER * peak:
        return t, x, q
    longest = min(int(SMOOTH_MAX_S / h) // 2 * 2 + 1, (len(t) - 1) // 2 * 2 + 1)
    window = VELOCITY_WINDOW
    while window < longest and _velocity_noise_gain(window) * sigma / h > NOISE_TARGET * peak:
        window += 2
    window = min(window, longest)
    if window <= VELOCITY_ORDER + 1:
        return t, x, q
    what = f"about {_length(_noise_deviation(x), q is not None)}"
    x = savgol(x, window, VELOCITY_ORDER)
    if q is not None:
        ref = q[-1]
        r = rotation_vectors(q, ref)
        what += f" and {np.degrees(_noise_deviation(r)):.2g} deg"
        q = continuous(from_rotation_vectors(savgol(r, window, VELOCITY_ORDER), ref))
    moved = "positions and orientations" if q is not None else "positions"
    notes.append(f"{where}: {moved} smoothed over {window * h:.2g} s ({window} samples, cubic Savitzky-Golay): "
                 f"their noise, {what}, would make its velocities noisy")
    return t, x, q


# ---------------------------------------------------------------- 3. and 4. standing still, pauses

def _stillness(t: np.ndarray, x: np.ndarray, q: np.ndarray | None, y: np.ndarray, sigma: np.ndarray,
               steps: frozenset[str], where: str, notes: list[str], duration: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Trim one demo's standing still ("still" in ``steps``) and cut its pauses ("pauses").

    Samples a .. b stand still when (1) the means m_k of y over the ``STILL_AVERAGE`` samples centred
    on each (n_k of them, fewer at the ends) lie within ``STILL_NOISE_K`` sigma_j / sqrt(n_k) + F of one
    point in every coordinate j, and (2) the least-squares line of each coordinate through y_a .. y_b
    rises over them by at most ``STILL_DRIFT_K`` times its noise deviation, sigma_j (t_b - t_a) /
    sqrt(sum_k (t_k - mean t)^2), + F; F is ``STILL_FLOOR`` times the largest extent of a coordinate.
    The longest such stretch from the first sample, if it lasts ``START_STILL_S`` and
    ``STILL_MIN_SAMPLES``, is trimmed to its last ``STILL_MARGIN_S``; the longest to the last sample,
    if it lasts ``END_STILL_S`` and ``STILL_MIN_SAMPLES``, to its first. Pauses between them
    (``_pauses``) are cut to ``STILL_MARGIN_S`` (half on each side) and later times are moved back.

    t (T,) [s], x (T, d), q (T, 4) or None are the demo as the earlier steps left it (what is cut);
    y (T, d'), d' = d or d + 3, its points (``_coordinates``) as recorded, before smoothing (what is
    judged); sigma (d',) their noise deviations (``_noise_deviations``); duration [s] the recording's.
    A demo that stands still from start to end is a ``DemoError`` (with "still" in ``steps``).
    """
    T = len(t)
    extent = float(np.max(np.ptp(y, axis=0)))
    if not np.isfinite(extent) or not extent > 0 or not np.all(np.isfinite(sigma)):
        return t, x, q                                 # values too large to measure: left as they are
    c = np.concatenate([np.zeros((1, y.shape[1])), np.cumsum(y - y[0], axis=0)])
    k = np.arange(T)
    lo, hi = np.maximum(k - STILL_AVERAGE // 2, 0), np.minimum(k + STILL_AVERAGE // 2 + 1, T)
    n = (hi - lo)[:, None].astype(np.float64)
    mean = y[0] + (c[hi] - c[lo]) / n
    tol = STILL_NOISE_K * sigma / np.sqrt(n) + STILL_FLOOR * extent
    low, high = mean - tol, mean + tol                 # a stretch stands still where these overlap
    u = (t - t[0])[:, None]
    sums = [np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(v, axis=0)])
            for v in (np.ones_like(u), u, u * u, y - y[0], u * (y - y[0]))]

    def level(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Condition (2) for the stretches a .. b, a and b of shape (M,): shape (M,)."""
        n, su, suu, sy, suy = (c[b + 1] - c[a] for c in sums)
        stt = np.maximum(suu - su * su / n, 0.0)
        rise = np.abs(suy - su * sy / n)               # the rise times stt / (t_b - t_a)
        duration = np.maximum(t[b] - t[a], np.finfo(float).tiny)[:, None]
        bound = STILL_DRIFT_K * sigma * np.sqrt(stt) + STILL_FLOOR * extent * stt / duration
        return np.all((rise <= bound) | (n < 2), axis=1)     # one sample: no line (its rise is rounding)

    ends = np.arange(_still_prefix(low, high) + 1)     # samples 0 .. b, b in ends, meet condition (1)
    first = int(ends[level(np.zeros_like(ends), ends)][-1])     # samples 0 .. first stand still
    starts = np.arange(T - 1 - _still_prefix(low[::-1], high[::-1]), T)
    last = int(starts[level(starts, np.full_like(starts, T - 1))][0])   # samples last .. T - 1 stand still
    if first == T - 1 and "still" in steps:
        raise DemoError(f"{where} stays within its noise (about {_length(float(np.max(sigma)), q is not None)}) "
                        "from start to end: it does not move; record the motion, or leave it out")
    if first >= last:                                  # it barely leaves its noise: nothing is judged still
        return t, x, q
    runs = []
    if "still" in steps and t[first] - t[0] >= START_STILL_S and first + 1 >= STILL_MIN_SAMPLES:
        runs.append((0, first))
    if "pauses" in steps:
        runs += _pauses(t, mean, low, high, 2.0 * tol.min(axis=0), first, last, level)
    if "still" in steps and t[-1] - t[last] >= END_STILL_S and T - last >= STILL_MIN_SAMPLES:
        runs.append((last, T - 1))
    if not runs:
        return t, x, q
    h = float(np.median(np.diff(t)))
    keep = np.ones(T, dtype=bool)
    shift = np.zeros(T)
    trimmed: list[str] = []
    pauses = []
    removed = cut = 0.0
    for a, b in runs:
        if a == 0:
            begin = int(np.searchsorted(t, t[b] - STILL_MARGIN_S))
            keep[:begin] = False
            shift[begin:] -= t[begin] - t[0]
            removed += t[begin] - t[0]
            trimmed.append(f"{t[begin] - t[0]:.2g} s standing still at the start")
        elif b == T - 1:
            end = int(np.searchsorted(t, t[a] + STILL_MARGIN_S, side="right")) - 1
            keep[end + 1:] = False
            removed += t[-1] - t[end]
            trimmed.append(f"{t[-1] - t[end]:.2g} s" + (" at the end" if trimmed else " standing still at the end"))
        else:
            i1 = int(np.searchsorted(t, t[a] + STILL_MARGIN_S / 2, side="right")) - 1
            i2 = int(np.searchsorted(t, t[b] - STILL_MARGIN_S / 2))
            if i2 - i1 < 2:                                # sampled too coarsely to cut anything
                continue
            keep[i1 + 1:i2] = False
            shift[i2:] -= t[i2] - t[i1] - h
            cut += t[i2] - t[i1] - h
            pauses.append(f"at {t[a] - t[0]:.3g} s by {t[i2] - t[i1] - h:.2g} s")
    if keep.all():
        return t, x, q
    if trimmed:
        notes.append(f"{where}: trimmed {' and '.join(trimmed)} (it stayed within its noise)"
                     + _share(removed, duration))
    if pauses:
        which = f"a pause {pauses[0]}, to" if len(pauses) == 1 else f"pauses {_and(pauses)}, each to"
        notes.append(f"{where}: shortened {which} {STILL_MARGIN_S:g} s (it stayed within its noise); later "
                     "times moved back" + _share(cut, duration))
    t = (t + shift)[keep]
    return t, x[keep], None if q is None else q[keep]


def _still_prefix(low: np.ndarray, high: np.ndarray) -> int:
    """The last index b such that the intervals [low_k, high_k] (T, d), k <= b, share a point in every
    coordinate."""
    apart = np.any(np.maximum.accumulate(low, axis=0) > np.minimum.accumulate(high, axis=0), axis=1)
    return int(np.argmax(apart)) - 1 if apart.any() else len(low) - 1


def _pauses(t: np.ndarray, mean: np.ndarray, low: np.ndarray, high: np.ndarray, away: np.ndarray,
            first: int, last: int, level: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> list[tuple[int, int]]:
    """The pauses (a, b), in order, of a demo whose samples 0 .. first and last .. T - 1 stand still:
    stretches a .. b, first < a <= b < last, of ``PAUSE_S`` and ``STILL_MIN_SAMPLES`` or more, that stand
    still (``_stillness``: their intervals [low_k, high_k] (T, d) share a point, and ``level(a, b)``)
    and before and after which the mean position (T, d) is further than ``away`` (d,) from their middle
    in some coordinate (real moves, not a creep out of or into a rest); the longest first, none
    overlapping another."""
    h = float(np.median(np.diff(t)))
    m = max(STILL_MIN_SAMPLES, int(np.ceil(PAUSE_S / h - 1e-9)) + 1)   # samples of the shortest pause
    if last - first - 1 < m:
        return []
    seeds = np.all(_window_extremes(low[first + 1:last], m, np.maximum)
                   <= _window_extremes(high[first + 1:last], m, np.minimum), axis=1)
    edges = np.flatnonzero(np.diff(np.r_[0, seeds.astype(np.int8), 0]))
    found = []
    for s0, s1 in zip(edges[::2], edges[1::2]):        # samples a0 + i .. a0 + i + m - 1 stand still, i < s1 - s0,
        a0 = first + 1 + int(s0)                       # and no stretch of m samples or more reaches further
        reach = a0 + _reaches(low[a0:first + int(s1) + m], high[a0:first + int(s1) + m])
        found += [(float(t[b] - t[a]), a, int(b)) for a, b in enumerate(reach, a0) if t[b] - t[a] >= PAUSE_S]
    before = np.maximum.accumulate(mean, axis=0), np.minimum.accumulate(mean, axis=0)
    after = np.maximum.accumulate(mean[::-1], axis=0)[::-1], np.minimum.accumulate(mean[::-1], axis=0)[::-1]
    taken: list[tuple[int, int]] = []
    for _, a, b in sorted(found, key=lambda f: (-f[0], f[1])):
        if any(a <= d and c <= b for c, d in taken) or not level(np.array([a]), np.array([b]))[0]:
            continue
        middle = (low[a:b + 1].max(axis=0) + high[a:b + 1].min(axis=0)) / 2
        if all(np.any((up[i] > middle + away) | (down[i] < middle - away)) for (up, down), i in ((before, a - 1),
                                                                                                 (after, b + 1))):
            taken.append((a, b))
    return sorted(taken)


def _window_extremes(v: np.ndarray, m: int, pick: np.ufunc) -> np.ndarray:
    """The maxima (``pick`` np.maximum) or minima (np.minimum) of each coordinate over each m consecutive
    samples of v (L, d), shape (L - m + 1, d): by doubling, windows of 1, 2, 4, ... samples, then two
    overlapping ones."""
    w, k = v, 1
    while 2 * k <= m:
        w, k = pick(w[:-k], w[k:]), 2 * k
    return pick(w[:len(w) - (m - k)], w[m - k:])


def _reaches(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """For each sample i of the intervals [low, high] (L, d), the last index j such that those of i .. j
    share a point in every coordinate, shape (L,): two pointers, with a monotone queue of the largest
    low and one of the smallest high in each coordinate."""
    lows, highs, (L, d) = low.tolist(), high.tolist(), low.shape
    top: list[deque[int]] = [deque() for _ in range(d)]      # indices of decreasing lows
    bottom: list[deque[int]] = [deque() for _ in range(d)]   # indices of increasing highs
    reach = np.empty(L, dtype=np.int64)
    j = -1
    for i in range(L):
        while j + 1 < L and (j < i or all(max(lows[top[c][0]][c], lows[j + 1][c])
                                          <= min(highs[bottom[c][0]][c], highs[j + 1][c]) for c in range(d))):
            j += 1
            for c in range(d):
                while top[c] and lows[top[c][-1]][c] <= lows[j][c]:
                    top[c].pop()
                top[c].append(j)
                while bottom[c] and highs[bottom[c][-1]][c] >= highs[j][c]:
                    bottom[c].pop()
                bottom[c].append(j)
        reach[i] = j
        for queue in (*top, *bottom):
            if queue[0] == i:
                queue.popleft()
    return reach


def _line_speed(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The speed (T,) of y (T, d) at each sample: the slope of the least-squares line through the samples
    within ``STILL_WINDOW_S`` / 2 of it (at least ``_SIDE_SAMPLES`` on each side, fewer at the ends), by
    running sums. A line over many samples averages the noise out far better than a derivative."""
    T = len(t)
    u = t - t[0]
    k = np.arange(T)
    half = STILL_WINDOW_S / 2
    lo = np.minimum(np.searchsorted(u, u - half), np.maximum(k - _SIDE_SAMPLES, 0))
    hi = np.maximum(np.searchsorted(u, u + half, side="right"), np.minimum(k + _SIDE_SAMPLES + 1, T))

    def window_sum(a: np.ndarray) -> np.ndarray:
        c = np.concatenate([np.zeros((1, *a.shape[1:])), np.cumsum(a, axis=0)])
        return c[hi] - c[lo]

    n = (hi - lo).astype(np.float64)
    yc = y - y.mean(axis=0)
    st, stt = window_sum(u), window_sum(u * u)
    sy, sty = window_sum(yc), window_sum(u[:, None] * yc)
    slope = (sty - (st / n)[:, None] * sy) / (stt - st * st / n)[:, None]
    return np.linalg.norm(slope, axis=1)


# ---------------------------------------------------------------- the set

def _resample_note(cleaned: list[tuple[np.ndarray, np.ndarray, np.ndarray | None, list[str]]], name: str) -> str:
    """One line: the demos were resampled to the longest length (and their rates, when they differ)."""
    lengths = [len(c[0]) for c in cleaned]
    rates = [1.0 / float(np.median(np.diff(c[0]))) for c in cleaned]
    text = (f"{name}: demos resampled to {max(lengths)} samples each, evenly in time "
            f"(they had {min(lengths)} to {max(lengths)}")
    if max(rates) > 1.01 * min(rates):
        text += f", at {min(rates):.3g} to {max(rates):.3g} Hz"
    return text + ")"


def _spread_note(ends: np.ndarray, x: np.ndarray, end_q: np.ndarray | None, name: str) -> str | None:
    """One line when the end points lie further than ``GOAL_TOLERANCE`` of the extent from their mean,
    or the final orientations further than ``GOAL_ANGLE_TOLERANCE`` from theirs; None otherwise."""
    d = x.shape[-1]
    extent = float(np.max(np.ptp(x.reshape(-1, d), axis=0)))
    miss = float(np.max(np.linalg.norm(ends - ends.mean(axis=0), axis=1)))
    apart = float(np.max(np.linalg.norm(ends[:, None] - ends[None], axis=-1)))
    turned = angle = 0.0
    if end_q is not None and len(end_q) > 1:
        rots = quaternion_matrices(end_q)
        turned = float(np.degrees(np.max(geodesic_angle(quaternion_matrices(mean_quaternion(end_q)), rots))))
        angle = float(np.degrees(np.max(geodesic_angle(rots[:, None], rots[None]))))
    parts = []
    if miss > GOAL_TOLERANCE * extent:
        parts.append(f"{_length(apart, end_q is not None)} apart ({apart / extent:.0%} of the extent)")
    if turned > GOAL_ANGLE_TOLERANCE:
        parts.append(f"{angle:.0f} deg apart in orientation")
    if not parts:
        return None
    return f"{name}: demos end up to {' and '.join(parts)}; each demo is learned relative to its own end"
