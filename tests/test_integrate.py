"""lfd.integrate: the solver table, its options, the batched rollouts and the numpy point integrators."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch
from scipy.linalg import expm
from torchdiffeq._impl.odeint import SOLVERS as TORCHDIFFEQ_SOLVERS

from lfd import integrate
from lfd.demos import DemoSet
from lfd.evaluation import reproduce
from lfd.field import VelocityField
from lfd.threads import torch_threads

pytestmark = pytest.mark.usefixtures("one_thread")

A = np.array([[-1.0, 3.0], [-3.0, -1.0]])   # the spiral_field_2d fixture: f(x) = A (x - g)
G = np.array([0.5, -0.25])


def exact(x0: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The flow of f(x) = A (x - G): x(t) = G + expm(A t) (x0 - G), shape (T, d)."""
    return np.stack([G + expm(A * tk) @ (x0 - G) for tk in t])


def test_the_solver_table_partitions_into_fixed_step_and_adaptive() -> None:
    assert set(integrate.FIXED_STEP) | set(integrate.ADAPTIVE) == set(integrate.SOLVERS)
    assert not set(integrate.FIXED_STEP) & set(integrate.ADAPTIVE)
    assert {"euler", "midpoint", "heun2", "heun3", "rk4"} <= set(integrate.FIXED_STEP)
    assert {"dopri5", "bosh3"} <= set(integrate.ADAPTIVE)
    for name, solver in integrate.SOLVERS.items():   # every entry is a torchdiffeq method of that kind
        assert name in TORCHDIFFEQ_SOLVERS
        from torchdiffeq._impl.solvers import FixedGridODESolver

        assert issubclass(TORCHDIFFEQ_SOLVERS[name], FixedGridODESolver) == (not solver.adaptive), name


def test_heun3_honours_substeps(spiral_field_2d: VelocityField) -> None:
    """A fixed bug: ``rollout(..., method="heun3", substeps=4)`` ignored ``substeps``."""
    x0, t = np.array([1.5, 0.75]), np.linspace(0.0, 2.0, 21)
    one = spiral_field_2d.rollout(x0, t, method="heun3")
    four = spiral_field_2d.rollout(x0, t, method="heun3", substeps=4)
    err_one, err_four = np.abs(one - exact(x0, t)).max(), np.abs(four - exact(x0, t)).max()
    assert err_four < err_one / 20    # third order: 4x smaller steps, ~64x smaller error


@pytest.mark.parametrize("method", integrate.FIXED_STEP)
def test_every_fixed_step_solver_honours_substeps(spiral_field_2d: VelocityField, method: str) -> None:
    x0, t = np.array([1.5, 0.75]), np.linspace(0.0, 2.0, 41)
    ys = [spiral_field_2d.rollout(x0, t, method=method, substeps=n) for n in (1, 4)]
    if not integrate.SOLVERS[method].one_step:
        # torchdiffeq 0.2.5's Adams methods diverge on this stable focus at any step we tried
        # (|x| grows by tens of orders of magnitude), so only check that substeps reach them
        assert not np.array_equal(ys[0], ys[1], equal_nan=True), method
        return
    err = [np.abs(y - exact(x0, t)).max() for y in ys]
    assert err[1] < err[0] / 3, (method, err)


def test_substeps_equal_an_explicit_step(spiral_field_2d: VelocityField) -> None:
    x0, t = np.array([[1.5, 0.75], [-1.0, 0.2]]), np.linspace(0.0, 1.0, 11)
    a = spiral_field_2d.rollout(x0, t, method="rk4", substeps=5)
    b = integrate.rollout(spiral_field_2d, x0, t, method="rk4", step=float(np.min(np.diff(t))) / 5)
    np.testing.assert_array_equal(a, b)


def test_options_a_solver_would_ignore_are_refused(spiral_field_2d: VelocityField) -> None:
    x0, t = np.array([1.5, 0.75]), np.linspace(0.0, 1.0, 5)
    with pytest.raises(ValueError, match="adaptive"):
        spiral_field_2d.rollout(x0, t, method="dopri5", substeps=4)
    with pytest.raises(ValueError, match="unknown solver 'rk5'"):
        spiral_field_2d.rollout(x0, t, method="rk5")
    with pytest.raises(ValueError, match="substeps"):
        spiral_field_2d.rollout(x0, t, substeps=0)
    with pytest.raises(ValueError, match="fixed steps"):
        integrate.odeint_kwargs("rk4", rtol=1e-3)


def test_odeint_kwargs() -> None:
    assert integrate.odeint_kwargs("rk4") == {"method": "rk4"}
    assert integrate.odeint_kwargs("heun3", substeps=4, t=np.array([0.0, 0.1, 0.3])) == {
        "method": "heun3", "options": {"step_size": 0.1 / 4}}
    assert integrate.odeint_kwargs("rk4", step=0.5, interp="cubic") == {
        "method": "rk4", "options": {"step_size": 0.5, "interp": "cubic"}}
    assert integrate.odeint_kwargs("dopri5", rtol=1e-6, atol=1e-7, max_steps=10) == {
        "method": "dopri5", "rtol": 1e-6, "atol": 1e-7, "options": {"max_num_steps": 10}}


def test_adaptive_rollout_meets_its_tolerance(spiral_field_2d: VelocityField) -> None:
    x0, t = np.array([1.5, 0.75]), np.linspace(0.0, 2.0, 11)
    np.testing.assert_allclose(spiral_field_2d.rollout(x0, t, method="dopri5"), exact(x0, t), atol=1e-7)


def test_sample_units_batch_demos_on_their_own_clocks(spiral_field_2d: VelocityField) -> None:
    t = np.stack([np.linspace(0.0, 2.0, 30), np.linspace(1.0, 4.0, 30)])
    x0 = np.array([[1.5, 0.75], [-1.0, 0.2]])
    demos = DemoSet(t, np.stack([spiral_field_2d.rollout(x, ti - ti[0]) for x, ti in zip(x0, t)]))
    ys = integrate.rollout_sample_units(spiral_field_2d, x0, t[:, 1:2] - t[:, :1], 30, "heun3")
    ref = np.stack([spiral_field_2d.rollout(x, ti - ti[0], method="heun3") for x, ti in zip(x0, t)])
    np.testing.assert_allclose(ys, ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(reproduce(spiral_field_2d, demos, method="heun3"), ref, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="one-step"):
        integrate.rollout_sample_units(spiral_field_2d, x0, t[:, 1:2], 30, "explicit_adams")


# ---- numpy point integrators

def _classic_rk4_reference(f: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, t: np.ndarray,
                           substeps: int) -> np.ndarray:
    """sim.run.experiment.integrate as it was: the loop ``lfd.integrate.rk4`` must equal bit for bit."""
    x = np.asarray(x0, dtype=np.float64).copy()
    out = np.empty((len(t), len(x)))
    out[0] = x
    for k in range(1, len(t)):
        h = (t[k] - t[k - 1]) / substeps
        for _ in range(substeps):
            k1 = f(x)
            k2 = f(x + 0.5 * h * k1)
            k3 = f(x + 0.5 * h * k2)
            k4 = f(x + h * k3)
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out[k] = x
    return out


def test_point_rk4_is_classic_rk4_and_agrees_with_the_batched_rollout(spiral_field_2d: VelocityField) -> None:
    f = spiral_field_2d.single_point_evaluator()
    x0, t = np.array([1.5, 0.75]), np.linspace(0.0, 2.0, 101)
    got = integrate.rk4(f, x0, t, substeps=2)
    np.testing.assert_array_equal(got, _classic_rk4_reference(f, x0, t, 2))
    np.testing.assert_allclose(got, exact(x0, t), rtol=0, atol=1e-7)
    # torchdiffeq's rk4 is the 3/8 rule: the same order, not the same floats
    np.testing.assert_allclose(got, spiral_field_2d.rollout(x0, t, substeps=2), rtol=0, atol=1e-7)


def test_point_rk4_phase() -> None:
    """x' = -x with a phase s' = 1 that stops at 1: s(t) = min(t, 1), x = x0 e^-t."""
    def fn(x: np.ndarray, s: float) -> tuple[np.ndarray, float]:
        return -x, 1.0

    t = np.linspace(0.0, 2.0, 41)
    xs, ss = integrate.rk4_phase(fn, np.array([1.0, -2.0]), t, substeps=2)
    np.testing.assert_allclose(xs, np.exp(-t)[:, None] * np.array([1.0, -2.0]), rtol=1e-7)
    np.testing.assert_allclose(ss, np.minimum(t, 1.0), atol=1e-12)
    assert ss.max() == 1.0


def test_rk4_step_is_fourth_order() -> None:
    errs = []
    for h in (0.1, 0.05):
        x = np.array([1.0])
        for k in range(int(round(1.0 / h))):
            x = integrate.rk4_step(lambda y, tk: tk * y, x, k * h, h)   # x' = t x: x(1) = e^(1/2)
        errs.append(abs(float(x[0]) - np.exp(0.5)))
    assert 12 < errs[0] / errs[1] < 20


def test_torch_threads_restores_the_count() -> None:
    before = torch.get_num_threads()
    with pytest.raises(KeyboardInterrupt):
        with torch_threads(1):
            assert torch.get_num_threads() == 1
            raise KeyboardInterrupt
    assert torch.get_num_threads() == before


# ---- docs/equations.md, the map from the paper's equations to this code

def test_the_equation_map_covers_every_equation_and_names_real_code() -> None:
    import importlib
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "equations.md").read_text()
    rows = re.findall(r"^\| \((\d+)\) \|", text, flags=re.M)
    assert [int(r) for r in rows] == list(range(1, 19))
    names = set(re.findall(r"`(lfd(?:\.\w+)+)`", text))
    assert len(names) > 15
    for name in sorted(names):
        parts = name.split(".")
        for cut in range(len(parts), 0, -1):   # the longest importable module, then attributes
            try:
                obj: object = importlib.import_module(".".join(parts[:cut]))
            except ImportError:
                continue
            for attr in parts[cut:]:
                obj = getattr(obj, attr)
            break
