"""kinadapt_nn: learn a robot's task Jacobian online, by feel.

A Franka Panda (MuJoCo) holds a peg of unknown geometry and inserts it into a square bore
using only joint encoders and a wrist force/torque sensor. The sensor Jacobian estimate is
factorised ``J_hat = Y(q) theta`` (eq. adaptive_factorization / ft_factor) and ``theta`` is
adapted online (default: the kalman law; the paper's composite law, eq. ft_composite, is a mode)
inside a second-order admittance loop (eq. cp_admittance).

Equation labels cited anywhere in the code ("eq. ft_composite", "Theorem ft_rigid", ...) are
stated, in this package's notation and with their meaning, in ``docs/equations.md#<label>``
(the preprint is not needed to follow them).

Symbols used throughout (shapes in docstrings refer to them):
    n = 7   joints of the Panda
    m = 6   sensor channels, s = [d, F_lat_x, F_lat_y, M_x, M_y, M_z]
    p       number of adapted parameters theta (3 for the adjoint features)
    B       batch size

Frames: ``w`` world (z up; the bore axis points along -z into the hole), ``f`` flange /
F/T-sensor frame (origin O), ``t`` tool. ``offset_f`` is the vector O -> tip in ``f``.
Units are SI throughout (m, N, N m, rad, s).
"""

__version__ = "0.1.0"
