"""Ground truth for soft manipulators: PCC model specs, symbolic equations of motion (CasADi),
generated C code, simulation and dataset files. Never imports jax.

Core API::

    from softpinn.symbolic import functions, TrueModel
    fns = functions("task4")          # dict of casadi.Function: M, M_inv, G, D, A, C, Cqd,
                                      # forward, inverse, energy, kinetic, potential,
                                      # momentum, hamiltonian, ode
    tm = TrueModel("task4")           # numpy face: tm.M(q), tm.qdd(q, qd, u), ... (batched)
"""

from __future__ import annotations

from softpinn.errors import UserError
from softpinn.symbolic._outputs import count_of, dumps
from softpinn.symbolic.codegen import _kernel
from softpinn.symbolic.codegen._codegen import CompilerWarning, cache_dir, compile_functions
from softpinn.symbolic.codegen._compiler import (
    DEFAULT_FLAGS,
    DEFAULT_TIMEOUT,
    CompilerTimeout,
    find_compiler,
)
from softpinn.symbolic.codegen._generate import generate, read_derive_summary
from softpinn.symbolic.codegen._kernel import RK4 as KernelRK4
from softpinn.symbolic.codegen._kernel import available as kernels_available
from softpinn.symbolic.codegen._kernel_source import expand as expand_sx
from softpinn.symbolic.derivation._eom import SymbolicModel, derive
from softpinn.symbolic.derivation._kinematics import planar_plate, spatial_tip
from softpinn.symbolic.derivation._shape import PCC_KINDS, backbone_points
from softpinn.symbolic.model._functions import SIGNATURES, functions, functions_of
from softpinn.symbolic.model._true_model import TrueModel
from softpinn.symbolic.recorded._filters import parse_smoother
from softpinn.symbolic.recorded._import import _version, import_recordings
from softpinn.symbolic.recorded._template import write_template
from softpinn.symbolic.simulation._datafile import (
    DatasetArrays,
    read_dataset,
    resample,
    select_trajectories,
    write_dataset,
    write_datasets,
)
from softpinn.symbolic.simulation._datasets import (
    DatasetPlan,
    check_seed,
    draw_trajectories,
    make_dataset,
    package_version,
    plan_dataset,
)
from softpinn.symbolic.simulation._datatable import data_config
from softpinn.symbolic.simulation._defaults import physics_data_table
from softpinn.symbolic.simulation._equilibria import Equilibria, attach, equilibria
from softpinn.symbolic.simulation._farm import ray_init, ray_simulator
from softpinn.symbolic.simulation._samples import condition_numbers, in_threads
from softpinn.symbolic.simulation._signals import Signal
from softpinn.symbolic.simulation._sim_config import (
    SimResult,
    SimulationConfig,
    SimulationError,
    SingularityError,
)
from softpinn.symbolic.spec._model_spec import ModelSpec, Segment, SpecError
from softpinn.symbolic.spec._recipe import LOSS_KEYS, MODEL_KEYS
from softpinn.symbolic.spec._sensor import SensorConfig, record, sensor_config, write_csv
from softpinn.symbolic.spec._spec import list_presets, load_spec
from softpinn.symbolic.standin._cosserat import QUICK as COSSERAT_QUICK
from softpinn.symbolic.standin._cosserat import CosseratArm
from softpinn.symbolic.standin._cosserat import RecordSettings as CosseratRecordSettings
from softpinn.symbolic.standin._cosserat import record_settings as record_cosserat

__all__ = [
    "_kernel",
    "_version",
    "attach",
    "backbone_points",
    "cache_dir",
    "check_seed",
    "compile_functions",
    "CompilerTimeout",
    "CompilerWarning",
    "condition_numbers",
    "COSSERAT_QUICK",
    "CosseratArm",
    "CosseratRecordSettings",
    "count_of",
    "data_config",
    "DatasetArrays",
    "DatasetPlan",
    "DEFAULT_FLAGS",
    "DEFAULT_TIMEOUT",
    "derive",
    "draw_trajectories",
    "dumps",
    "Equilibria",
    "equilibria",
    "expand_sx",
    "find_compiler",
    "functions",
    "functions_of",
    "generate",
    "import_recordings",
    "in_threads",
    "KernelRK4",
    "kernels_available",
    "list_presets",
    "load_spec",
    "LOSS_KEYS",
    "make_dataset",
    "MODEL_KEYS",
    "ModelSpec",
    "package_version",
    "parse_smoother",
    "PCC_KINDS",
    "physics_data_table",
    "plan_dataset",
    "planar_plate",
    "ray_init",
    "ray_simulator",
    "read_dataset",
    "read_derive_summary",
    "record",
    "record_cosserat",
    "resample",
    "Segment",
    "select_trajectories",
    "sensor_config",
    "SensorConfig",
    "Signal",
    "SIGNATURES",
    "SimResult",
    "SimulationConfig",
    "SimulationError",
    "SingularityError",
    "spatial_tip",
    "SpecError",
    "SymbolicModel",
    "TrueModel",
    "UserError",
    "write_csv",
    "write_dataset",
    "write_datasets",
    "write_template",
]
