"""Model-predictive control with learned models: CasADi, generated C, the true model as plant.

    from softpinn.bridge.control import MPC, ControlConfig, MPCConfig, compare, from_run, tip_output
    result = compare("task4", ["runs/lnn"], "control-out")      # what `softpinn control` does
    compare("task4", ["runs/lnn"], None, ControlConfig(mpc=MPCConfig(horizon=10),
                                                       references=("step",)))

    # or piece by piece:
    model = from_run("runs/lnn", tip_output(spec), export_dir="exported/lnn")
    mpc = MPC(model, MPCConfig(horizon=20, dt=0.02))
    u, info = mpc.solve(q, qd, reference, u_prev)   # reference: (horizon, ny) outputs

See docs/control.md.
"""

from softpinn.bridge.control.compare import compare
from softpinn.bridge.control.config import LARGE_ARM_N, REFERENCES, ControlConfig, arm_defaults
from softpinn.bridge.control.loop import closed_loop, metrics, plant
from softpinn.bridge.control.models import (
    PredictionModel,
    from_export,
    from_run,
    from_true,
    linearised,
    output_label,
    resolve_run,
    tip_output,
)
from softpinn.bridge.control.mpc import MPC, QP_SOLVERS, SENSITIVITIES, SOLVERS, MPCConfig, rk4_map
from softpinn.bridge.control.references import (
    circle_reference,
    circle_start,
    default_center,
    default_input_bounds,
    default_radius,
    equilibrium,
    step_reference,
    step_targets,
)

__all__ = [
    "LARGE_ARM_N",
    "ControlConfig",
    "MPC",
    "MPCConfig",
    "PredictionModel",
    "QP_SOLVERS",
    "SENSITIVITIES",
    "REFERENCES",
    "SOLVERS",
    "arm_defaults",
    "circle_reference",
    "circle_start",
    "closed_loop",
    "compare",
    "default_center",
    "default_input_bounds",
    "default_radius",
    "equilibrium",
    "from_export",
    "from_run",
    "from_true",
    "linearised",
    "metrics",
    "output_label",
    "plant",
    "resolve_run",
    "rk4_map",
    "step_reference",
    "step_targets",
    "tip_output",
]
