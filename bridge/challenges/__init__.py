"""The paper's three open challenges (Section VI-B), each a study of ``softpinn reproduce
challenges``: fast Lagrangian training (:mod:`.fast`), the ideal Lagrangian solution by a known
actuator model (:mod:`.known`) and by additional labels (:mod:`.labels`), and Hamiltonian
networks from velocity data (:mod:`.velocity`).

Every study module has one entry point with the same contract::

    def run_study(out: Path, *, quick: bool, log: Callable[[str], None],
                  progress: ProgressFn | None = None) -> dict

``out`` is a folder the study owns (created for it, possibly holding an earlier call's
finished stages, which it may reuse); the study writes its runs and figures there and returns
``{"title": str, "markdown": str, "results": dict, "seconds": float}``: ``markdown`` is the
study's section of the report (figure links relative to ``out``'s parent, e.g.
``fast/time_to_loss.png``), ``results`` every number it measured (JSON-ready), ``seconds`` its
wall time. ``quick`` runs in about a minute per study on a 2-core machine (all four: 222 s in
the test suite, which runs it); the full form is what RESULTS.md reports.
"""
