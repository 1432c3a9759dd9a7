"""``softpinn reproduce cosserat`` (issue 43, item 4): the networks against no motion and
linear models on recordings of a Cosserat-rod stand-in arm, imported as a user
imports a real arm's (:mod:`.pipeline`; settings :mod:`.settings`; stages :mod:`.stages`)."""

from softpinn.bridge.cosserat.pipeline import MISSING_EXTRA, CosseratRun, run_cosserat
from softpinn.bridge.cosserat.settings import NETWORKS, CosseratPlan, make_plan

__all__ = ["CosseratPlan", "CosseratRun", "MISSING_EXTRA", "NETWORKS", "make_plan",
           "run_cosserat"]
