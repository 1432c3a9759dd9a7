"""The paper's three open challenges (Section VI-B), each a study of ``softpinn reproduce
challenges``: fast Lagrangian training (:mod:`.fast`), the ideal Lagrangian solution by a known
actuator model (:mod:`.known`) and by additional labels (:mod:`.labels`), and Hamiltonian
networks from velocity data (:mod:`.velocity`).

Every study module has one entry point with the same contract::

    def run_study(out: Path, *, quick: bool, log: Callable[[str], None],
                  progress: Callable[[dict], None] | None = None) -> dict

``out`` is a folder the study owns (created for it, possibly holding an earlier call's
finished stages, which it may reuse); the study writes its runs and figures there and returns
``{"title": str, "markdown": str, "results": dict, "seconds": float}``: ``markdown`` is the
study's section of the report (figure links relative to ``out``'s parent, e.g.
``fast/time_to_loss.png``), ``results`` every number it measured (JSON-ready), ``seconds`` its
wall time. ``quick`` runs in well under a minute on one core (CI runs it); the full form is what
RESULTS.md reports.
"""


def json_ready(x):
    """``x`` with non-finite floats as None, tuples as lists, numpy scalars as Python numbers
    and keys as strings: what every study writes to its ``results.json``."""
    import math

    import numpy as np

    if isinstance(x, dict):
        return {str(k): json_ready(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_ready(v) for v in x]
    if isinstance(x, float | np.floating):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x
