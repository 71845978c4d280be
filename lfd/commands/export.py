"""``lfd export``: write a model's velocity field for use outside Python (C++, ROS).

Formats (``--format``), each a function of user-unit positions x -> dx/dt in user units/s:

* ``torchscript``: ``torch.jit.trace`` of the learner's module with the normalisation folded in,
  f(x) = s f_n((x - goal) / s) (``UserUnitField``); input x, float64 tensor of shape (B, d), any B;
  output (B, d). Load with ``torch.jit.load`` (Python) or ``torch::jit::load`` (C++ libtorch).
* ``onnx``: the same module through ``torch.onnx.export`` (dynamo exporter), input ``x`` (B, d)
  float64 with a dynamic batch axis, output ``v`` (B, d). Needs the ``onnx`` and ``onnxscript``
  packages (``pip install 'lfd-arm[export]'``). Only models whose operations ONNX can express:
  the NODE exports; the contraction field's flow uses an eigen-decomposition (``aten._linalg_eigh``)
  and a linear solve that the exporter cannot convert, which ends in a clear error (use
  ``torchscript`` or ``npz-grid`` for it).
* ``npz-grid``: the field sampled on a regular grid, for lookup without any ML runtime: arrays
  ``axes`` (d, n), ``v`` (n, ..., n, d) (``indexing="ij"``), ``goal`` (d,), ``learner``,
  ``interpolation`` ("multilinear") and ``format`` ("lfd-npz-grid-1"); ``GridField`` says how to
  interpolate it. The default box is the training demos' box (``field.demo_box``) grown by 50%.

Every export is checked before it is written: the exported function (for ``npz-grid``, the grid
at its nodes) must reproduce ``field(x)`` to ``EXPORT_TOL`` x max(1, max |f|) at ``CHECK_POINTS``
seeded points over the normalised box [-1.5, 1.5]^d (the demos span [-1, 1]^d); otherwise
ModelError and nothing is written.
"""

from __future__ import annotations

import argparse
import io
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:  # imported when the command runs, so that ``lfd --help`` stays fast
    import numpy as np
    import torch

    from lfd.field import VelocityField

FORMATS: tuple[str, ...] = ("torchscript", "onnx", "npz-grid")
EXPORT_TOL = 1e-6          # relative to max(1, max |f|) over the check points
CHECK_POINTS = 256
GRID_DEFAULT = {2: 201, 3: 51}   # points per axis: 40 401 (2-D) or 132 651 (3-D) nodes; above, well under the cap
GRID_MAX_NODES = 5_000_000
GRID_FORMAT = "lfd-npz-grid-1"


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    from lfd.commands import MODEL_HELP
    from lfd.commands.certify import parse_box

    p = subparsers.add_parser("export", help="write a model's field as TorchScript, ONNX or an NPZ grid",
                              description=__doc__.splitlines()[0])
    p.add_argument("model", help=MODEL_HELP)
    p.add_argument("--format", required=True, choices=FORMATS, help="torchscript, onnx or npz-grid")
    p.add_argument("--out", required=True, metavar="PATH", help="file to write")
    p.add_argument("--grid", type=int, metavar="N",
                   help="npz-grid: points per axis (default 201 in 2-D, 51 in 3-D)")
    p.add_argument("--box", type=parse_box, metavar="XMIN,XMAX,YMIN,YMAX[,ZMIN,ZMAX]",
                   help="npz-grid: the box, user units; write --box=-1,1,-1,1 when it starts with a minus "
                        "(default: the training demos' box grown by 50%%)")
    return p


def run(args: argparse.Namespace) -> int:
    from lfd.commands import check_output
    from lfd.errors import ConfigError
    from lfd.learners import load

    if args.format != "npz-grid" and (args.grid is not None or args.box is not None):
        raise ConfigError("--grid and --box apply to --format npz-grid only")
    check_output(args.out, "--out", {"model file": args.model})
    field = load(args.model)
    if args.format == "torchscript":
        err = export_torchscript(field, args.out)
    elif args.format == "onnx":
        err = export_onnx(field, args.out)
    else:
        lo, hi = args.box if args.box is not None else (None, None)
        err = export_grid(field, args.out, n=args.grid, lo=lo, hi=hi)
    print(f"wrote {args.out} ({args.format}, {field.learner}, {field.dim}-D; max deviation from the "
          f"model {err:.2e} user units/s)")
    return 0


# ---------------------------------------------------------------- the exported function
def user_unit_module(field: VelocityField) -> torch.nn.Module:
    """f(x) = s f_n((x - goal) / s) as one float64 torch module: x (B, d) -> (B, d), user units."""
    import torch

    class UserUnitField(torch.nn.Module):
        """The learner's module with the normalisation of ``lfd.normalization`` folded in."""

        goal: torch.Tensor   # a buffer (register_buffer below)

        def __init__(self, module: torch.nn.Module, goal: np.ndarray, scale: float) -> None:
            super().__init__()
            self.module = module
            self.register_buffer("goal", torch.as_tensor(goal, dtype=torch.float64).reshape(1, -1))
            self.scale = float(scale)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return self.module((x - self.goal) / self.scale) * self.scale

    return UserUnitField(field.module, field.norm.goal, field.norm.scale).double().eval()


def check_points(field: VelocityField, n: int = CHECK_POINTS) -> np.ndarray:
    """n seeded points uniform over the normalised box [-1.5, 1.5]^d, in user units, shape (n, d)."""
    import numpy as np

    u = np.random.default_rng(0).uniform(-1.5, 1.5, size=(n, field.dim))
    return field.norm.from_norm(u)


def _deviation(field: VelocityField, x: np.ndarray, values: np.ndarray, what: str) -> float:
    """max |values - field(x)|; ModelError above EXPORT_TOL max(1, max |f|)."""
    import numpy as np

    from lfd.errors import ModelError

    ref = field(x)
    err = float(np.max(np.abs(np.asarray(values, dtype=np.float64) - ref)))
    bound = EXPORT_TOL * max(1.0, float(np.max(np.abs(ref))))
    if not err <= bound:
        raise ModelError(f"the {what} export does not reproduce the model: max deviation {err:.3g} > "
                         f"{bound:.3g} user units/s; nothing written")
    return err


def export_torchscript(field: VelocityField, path: str) -> float:
    """Trace ``user_unit_module(field)``, check it (module docstring) and write it atomically.
    Returns the max deviation from ``field`` at the check points (user units/s)."""
    import warnings

    import torch

    from lfd.errors import ModelError
    from lfd.io import atomic_write

    module = user_unit_module(field)
    x = check_points(field)
    buf = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        # torch >= 2.10 marks torch.jit deprecated; TorchScript is still what libtorch (C++) loads
        warnings.filterwarnings("ignore", message=r".*torch\.jit.* is deprecated")
        try:
            traced = torch.jit.trace(module, torch.from_numpy(x[:8].copy()), check_trace=False)
        except Exception as e:  # noqa: BLE001  (any tracer failure is the model's, reported in one line)
            raise ModelError(f"TorchScript cannot trace the {field.learner} field: {_first_line(e)}") from None
        # a batch size other than the one traced with: catches shapes frozen into the trace
        err = _deviation(field, x, traced(torch.from_numpy(x)).numpy(), "TorchScript")
        torch.jit.save(traced, buf)
    atomic_write(path, lambda f: f.write(buf.getvalue()))
    return err


def export_onnx(field: VelocityField, path: str) -> float:
    """Export ``user_unit_module(field)`` to ONNX with a dynamic batch axis, check it with
    ``onnx.reference.ReferenceEvaluator`` and write it atomically. Returns the max deviation."""
    import logging
    import warnings

    import torch

    from lfd.errors import ConfigError, ModelError
    from lfd.io import atomic_write

    try:
        import onnx  # noqa: F401
        import onnxscript  # noqa: F401
        from onnx.reference import ReferenceEvaluator
    except ImportError:
        raise ConfigError("--format onnx needs the onnx and onnxscript packages: "
                          "pip install 'lfd-arm[export]' (or use --format torchscript or npz-grid)") from None
    module = user_unit_module(field)
    x = check_points(field)
    quiet = logging.getLogger("torch.onnx")
    level = quiet.level
    quiet.setLevel(logging.ERROR)   # the exporter logs a line per absent optional package (torchvision)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(module, (torch.from_numpy(x[:8].copy()),), input_names=["x"],
                                        output_names=["v"], dynamo=True, verbose=False,
                                        dynamic_shapes={"x": {0: torch.export.Dim("batch")}})
    except Exception as e:  # noqa: BLE001  (any exporter failure is the model's, reported in one line)
        raise ModelError(f"ONNX cannot express the {field.learner} field ({_onnx_reason(e)}); "
                         "use --format torchscript or npz-grid") from None
    finally:
        quiet.setLevel(level)
    assert program is not None   # dynamo=True always returns an ONNXProgram
    data = program.model_proto.SerializeToString()
    # run() is annotated dict | list; without intermediate=True it returns the list of outputs
    values = cast(list[Any], ReferenceEvaluator(program.model_proto).run(None, {"x": x}))[0]
    err = _deviation(field, x, values, "ONNX")
    atomic_write(path, lambda f: f.write(data))
    return err


def _onnx_reason(e: BaseException) -> str:
    """The missing operator if the exporter names one, else the error's first line."""
    import re

    text = str(e)
    m = re.search(r"No ONNX function found for <OpOverload\(op='([^']+)'", text)
    return f"no ONNX operator for {m.group(1)}" if m else _first_line(e)


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


# ---------------------------------------------------------------- npz grid
def export_grid(field: VelocityField, path: str, n: int | None = None, lo: np.ndarray | None = None,
                hi: np.ndarray | None = None) -> float:
    """Sample the field on an n^d grid over [lo, hi] and write the NPZ (module docstring).

    lo, hi : array, shape (d,), user units (default: ``field.demo_box`` grown by 50%).
    Returns the max deviation of ``GridField`` from ``field`` at the grid nodes (0 up to round-off).
    """
    import numpy as np

    from lfd.errors import ConfigError, ModelError
    from lfd.io import atomic_write

    d = field.dim
    n = GRID_DEFAULT.get(d, max(2, int(GRID_MAX_NODES ** (1.0 / d) / 2))) if n is None else n
    if n < 2 or n ** d > GRID_MAX_NODES:
        raise ConfigError(f"--grid must be >= 2 with at most {GRID_MAX_NODES:,} nodes in all, got {n} "
                          f"({n ** d:,} nodes in {d}-D)")
    if lo is None or hi is None:
        from lfd.certify import BOX_GROWTH, default_box

        box = default_box(field, BOX_GROWTH)
        if box is None:
            raise ModelError("the model stores no demo box; give the grid's box with --box")
        lo, hi = box
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if lo.shape != (d,) or hi.shape != (d,) or not np.all(hi > lo):
        raise ConfigError(f"the box must give {d} ranges with max > min for this {d}-D model")
    axes = np.stack([np.linspace(a, b, n) for a, b in zip(lo, hi)])               # (d, n)
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)                 # (n, ..., n, d)
    with np.errstate(all="ignore"):
        v = field(nodes)
    if not np.isfinite(v).all():
        raise ModelError("the field is not finite on the whole grid; choose a smaller --box")
    grid = GridField(axes, v)
    pts = nodes.reshape(-1, d)[np.random.default_rng(0).choice(n ** d, size=min(CHECK_POINTS, n ** d),
                                                                  replace=False)]
    err = _deviation(field, pts, grid(pts), "npz-grid")
    buf = io.BytesIO()
    np.savez_compressed(buf, axes=axes, v=v, goal=np.asarray(field.goal, dtype=np.float64),
                        learner=np.array(field.learner), interpolation=np.array("multilinear"),
                        format=np.array(GRID_FORMAT))
    atomic_write(path, lambda f: f.write(buf.getvalue()))
    return err


class GridField:
    """Multilinear interpolation of an ``npz-grid`` export (bilinear in 2-D, trilinear in 3-D).

    axes : array, shape (d, n), the grid coordinates per axis, ascending; v : array, shape
    (n,)*d + (d,), v[i_1, ..., i_d] = f(axes[0, i_1], ..., axes[d-1, i_d]). With x in the cell
    [a_k, a_k + h_k] per axis and t_k = (x_k - a_k) / h_k,

        f(x) ~ sum over the 2^d corners c of prod_k (t_k if c_k = 1 else 1 - t_k) v[corner c],

    x clamped to the box first (the grid says nothing outside it); inside the box this equals
    ``scipy.interpolate.RegularGridInterpolator(method="linear")``, with an O(h^2) error between
    nodes. ``GridField.load(path)`` reads the file; calling it maps x, shape (..., d), to (..., d).
    """

    def __init__(self, axes: np.ndarray, v: np.ndarray) -> None:
        import numpy as np

        self.axes = np.asarray(axes, dtype=np.float64)
        self.v = np.asarray(v, dtype=np.float64)
        d, n = self.axes.shape
        if self.v.shape != (n,) * d + (d,):
            raise ValueError(f"grid values must have shape {(n,) * d + (d,)}, got {self.v.shape}")
        self.dim = d

    @classmethod
    def load(cls, path: str) -> GridField:
        import numpy as np

        from lfd.errors import ModelError

        with np.load(path, allow_pickle=False) as z:
            if "format" not in z.files or str(z["format"]) != GRID_FORMAT:
                raise ModelError(f"{path}: not an lfd npz-grid export ({GRID_FORMAT})")
            return cls(z["axes"], z["v"])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        import numpy as np

        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1] != self.dim:
            raise ValueError(f"grid field expects points of dimension {self.dim}, got shape {x.shape}")
        pts = x.reshape(-1, self.dim)
        n = self.axes.shape[1]
        idx, frac = [], []
        for k in range(self.dim):
            a = self.axes[k]
            xk = np.clip(pts[:, k], a[0], a[-1])
            i = np.clip(np.searchsorted(a, xk, side="right") - 1, 0, n - 2)   # cell [a_i, a_{i+1}]
            idx.append(i)
            frac.append((xk - a[i]) / (a[i + 1] - a[i]))
        out = np.zeros((len(pts), self.dim))
        for corner in range(2 ** self.dim):
            w = np.ones(len(pts))
            sel = []
            for k in range(self.dim):
                bit = (corner >> k) & 1
                w = w * (frac[k] if bit else 1.0 - frac[k])
                sel.append(idx[k] + bit)
            out += w[:, None] * self.v[tuple(sel)]
        return out.reshape(x.shape)
