"""Recordings as people make them: the clean-up of raw demos read from files and bags.

Each demo's raw arrays pass, in this order (docs/recordings.md states the rules and why):

1. time gaps (steps over ``GAP_FACTOR`` median steps): cut when the arm barely moved across one, filled
   by cubic Hermite interpolation when it moved on as the velocities beside it carry it and the gap
   is at most ``MAX_GAP_S``, else refused;
2. noise: positions and orientations smoothed (cubic Savitzky-Golay) when the noise estimated from
   their fourth differences would put more than ``NOISE_TRIGGER`` of the peak speed of noise into
   the velocities;
3. standing still: a stretch at the start (end) whose speed stays below ``STILL_FRACTION`` of the
   peak for at least ``START_STILL_S`` (``END_STILL_S``) is trimmed to ``STILL_MARGIN_S``;
4. pauses: such a stretch inside the demo, of ``START_STILL_S`` or more, is cut to ``STILL_MARGIN_S``
   and later times are moved back.

Then demos of different lengths are resampled to one, and ends spread beyond ``GOAL_TOLERANCE`` are
noted. Whatever is done is said in one note line; what cannot be mended is a ``DemoError`` of one
line. Nothing is done to a demo that needs nothing: its arrays pass through bit for bit. Speeds of a
pose weigh a turn of one radian as ``ROTATION_LENGTH`` metres. The shipped sets are never cleaned.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from lfd.demos.demoset import (
    GOAL_ANGLE_TOLERANCE,
    GOAL_TOLERANCE,
    MIN_SAMPLES,
    DemoSet,
    check_demo,
    resample,
)
from lfd.demos.smoothing import VELOCITY_ORDER, VELOCITY_WINDOW, savgol, savgol_coefficients
from lfd.errors import DemoError
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

GAP_FACTOR = 3.0        # a time step longer than this many median steps is a gap
MAX_GAP_S = 0.25        # s: the longest gap that is interpolated while the arm moves across it
GAP_SIDE_S = 0.1        # s: the velocity at a gap's edge is that of a parabola fitted over this time
GAP_CONTINUITY = 0.25   # a gap's jump may differ from what the motion carries by this fraction of it
NOISE_TRIGGER = 0.03    # smooth when the velocity noise exceeds this fraction of the peak speed
NOISE_TARGET = 0.01     # the smoothing window is the shortest that brings it below this fraction
SMOOTH_MAX_S = 0.5      # s: the longest smoothing window
STILL_FRACTION = 0.02   # still: speed below this fraction of the demo's peak speed
MOVING_FRACTION = 0.1   # moving clearly: speed above this fraction (a pause lies between such moves)
STILL_WINDOW_S = 0.5    # s: the speed is the slope of a line fitted over this time
START_STILL_S = 0.3     # s: the shortest still stretch trimmed at the start, or cut inside (a pause)
END_STILL_S = 1.5       # s: the shortest still stretch trimmed at the end (a slow arrival is kept)
STILL_MARGIN_S = 0.1    # s: what is kept of a trimmed or cut still stretch
_SIDE_SAMPLES = 2       # the speed's line spans at least this many samples on each side
_NOISE_K = 4.0          # a gap's jump may exceed the motion by this many noise deviations per coordinate
_MAD = 0.6744897501960817   # the median absolute deviation of a standard normal distribution


def recorded_set(ts: list[np.ndarray], xs: list[np.ndarray], qs: list[np.ndarray] | None, name: str) -> DemoSet:
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

    Returns
    -------
    DemoSet
        t (N, T), x (N, T, d), q (N, T, 4) or None, ``notes`` saying what was done, one line each.
    """
    cleaned = [clean_demo(t, x, None if qs is None else qs[i], name, i) for i, (t, x) in enumerate(zip(ts, xs))]
    notes = [note for *_, demo_notes in cleaned for note in demo_notes]
    lengths = [len(c[0]) for c in cleaned]
    if len(set(lengths)) > 1:
        notes.append(_resample_note(cleaned, name))
    t, x, q = resample([c[0] for c in cleaned], [c[1] for c in cleaned],
                       None if qs is None else [c[2] for c in cleaned if c[2] is not None], name)
    spread = _spread_note(x[:, -1], x, None if q is None else q[:, -1], name)
    if spread:
        notes.append(spread)
    return DemoSet(t, x, name=name, q=q, notes=tuple(notes))


def clean_demo(t: np.ndarray, x: np.ndarray, q: np.ndarray | None, name: str, index: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[str]]:
    """One raw demo cleaned up: gaps, noise, standing still, pauses (the module's rules, in order).

    Parameters
    ----------
    t, x, q, name, index
        As ``lfd.demos.demoset.check_demo``'s: times (T,) [s], positions (T, d), orientations
        (T, 4) (w, x, y, z) or None, and the set's name and the demo's index for the notes.

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
        What a ``DemoSet`` refuses, a gap that cannot be mended, or too few samples left.
    """
    check_demo(t, x, q, name, index)
    unit = None if q is None else continuous(q / np.linalg.norm(q, axis=1)[:, None])
    notes: list[str] = []
    where = f"{name}: demo {index}"
    with np.errstate(over="ignore", invalid="ignore"):    # huge but finite values: nothing is done to them
        tc, xc, qc = _gaps(t, x, unit, where, notes)
        tc, xc, qc = _noise(tc, xc, qc, where, notes)
        tc, xc, qc = _stillness(tc, xc, qc, where, notes)
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

def _gaps(t: np.ndarray, x: np.ndarray, q: np.ndarray | None, where: str, notes: list[str]
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Mend the gaps of one demo: steps over ``GAP_FACTOR`` median steps h. Beside a gap of length
    Delta, v_b and v_a are the velocities of y at its edges (parabolas fitted over ``GAP_SIDE_S``),
    v the larger speed, a the noise allowance (``_NOISE_K`` deviations per coordinate of both samples).
    If the jump |y_a - y_b| <= 2 v h + a, the arm barely moved across it (a pause the recorder
    missed): the gap is cut and later times are moved back. Else if the jump is what the motion
    carries, |y_a - y_b - (v_b + v_a) Delta / 2| <= ``GAP_CONTINUITY`` v Delta + a, and
    Delta <= ``MAX_GAP_S``, it is filled at the step h (positions by cubic Hermite interpolation,
    orientations by Slerp). Anything else is a ``DemoError``."""
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
    shift, cut, filled = 0.0, [], []
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
                     f"(the motion runs on across {'them' if len(filled) > 1 else 'it'})")
    if cut:
        notes.append(f"{where}: cut {_listed(cut, 'gap')} in its time stamps, across which it barely "
                     "moved; later times moved back")
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

def _stillness(t: np.ndarray, x: np.ndarray, q: np.ndarray | None, where: str, notes: list[str]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Trim one demo's standing still and cut its pauses: runs of samples whose speed (``_line_speed``
    of y) stays below ``STILL_FRACTION`` of its peak, at least ``START_STILL_S`` at the start or inside
    the demo (a pause: between moves above ``MOVING_FRACTION`` of the peak), at least ``END_STILL_S``
    at the end (a run after the last such move reaches the end). At the start (end) the run is trimmed to
    its last (first) ``STILL_MARGIN_S``; a pause is cut to ``STILL_MARGIN_S`` (half on each side) and
    later times are moved back, so that the demo runs on at its median step. Times keep the demo's
    start."""
    speed = _line_speed(t, _coordinates(x, q))
    peak = float(np.max(speed))
    if not np.isfinite(peak) or not peak > 0:           # values too large to measure: left as they are
        return t, x, q
    moving = np.flatnonzero(speed >= MOVING_FRACTION * peak)
    on, off = int(moving[0]), int(moving[-1])          # the motion: from the first to the last clear move
    still = speed < STILL_FRACTION * peak
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    T = len(t)
    found = list(zip(edges[::2].tolist(), (edges[1::2] - 1).tolist()))
    before = [b for a, b in found if b < on]           # standing still before the motion: from the start
    after = [a for a, b in found if a > off]           # after it: to the end (noise may stir the last samples)
    runs = [(0, before[-1])] if before and t[before[-1]] - t[0] >= START_STILL_S else []
    runs += [(a, b) for a, b in found if on < a and b < off and t[b] - t[a] >= START_STILL_S]
    runs += [(after[0], T - 1)] if after and t[-1] - t[after[0]] >= END_STILL_S else []
    if not runs:
        return t, x, q
    h = float(np.median(np.diff(t)))
    keep = np.ones(T, dtype=bool)
    shift = np.zeros(T)
    trimmed: list[str] = []
    pauses = []
    for a, b in runs:
        if a == 0:
            first = int(np.searchsorted(t, t[b] - STILL_MARGIN_S))
            keep[:first] = False
            shift[first:] -= t[first] - t[0]
            trimmed.append(f"{t[first] - t[0]:.2g} s standing still at the start")
        elif b == T - 1:
            last = int(np.searchsorted(t, t[a] + STILL_MARGIN_S, side="right")) - 1
            keep[last + 1:] = False
            trimmed.append(f"{t[-1] - t[last]:.2g} s" + (" at the end" if trimmed else " standing still at the end"))
        else:
            i1 = int(np.searchsorted(t, t[a] + STILL_MARGIN_S / 2, side="right")) - 1
            i2 = int(np.searchsorted(t, t[b] - STILL_MARGIN_S / 2))
            if i2 - i1 < 2:                                # sampled too coarsely to cut anything
                continue
            keep[i1 + 1:i2] = False
            shift[i2:] -= t[i2] - t[i1] - h
            pauses.append(f"at {t[a] - t[0]:.3g} s by {t[i2] - t[i1] - h:.2g} s")
    below = f"speed below {STILL_FRACTION:.0%} of its peak"
    if keep.all():
        return t, x, q
    if trimmed:
        notes.append(f"{where}: trimmed {' and '.join(trimmed)} ({below})")
    if pauses:
        which = f"a pause {pauses[0]}, to" if len(pauses) == 1 else f"pauses {_and(pauses)}, each to"
        notes.append(f"{where}: shortened {which} {STILL_MARGIN_S:g} s ({below}); later times moved back")
    t = (t + shift)[keep]
    return t, x[keep], None if q is None else q[keep]


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
