"""Trained networks for control: rebuilt in CasADi from their weights, written as serialized
Functions, generated C and metadata (``softpinn export``).

    from softpinn.bridge.export import export_run, load_exported
    export_run("runs/lnn", "exported/lnn")            # model.casadi, step.casadi, model.c, ...
    fns = load_exported("exported/lnn"); fns["qdd"](q, qd, u)
"""

from softpinn.bridge.export.dynamics import export_functions
from softpinn.bridge.export.params import model_params
from softpinn.bridge.export.writer import ExportResult, check_timeout, export_run, load_exported

__all__ = ["ExportResult", "check_timeout", "export_functions", "export_run", "load_exported",
           "model_params"]
