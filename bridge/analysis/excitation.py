"""How much a data set shows of the inertia in each direction of the true mass matrix.

A network learns M(q) from the inertial forces M q̈ the data hold. In a direction where those are
small beside the other forces of eq. 6 (the damping D q̇, the potential and input forces), M is
weakly determined there, and so are M⁻¹ and every product with it, whatever the loss. A light
segment is such a direction: Task 5's second segment bends with a mass about 100 times smaller
than the first's (the two smallest eigenvalues of M, which hold nearly all of ‖M⁻¹‖), so it is
overdamped (d/m about 185 1/s) and inputs well below that corner frequency move it
quasi-statically, D q̇ ≈ A u - G, with M q̈ a few percent of D q̇.

:func:`inertial_share` measures this on a data set with the true model: for each eigenvector v
of M(q) (lightest first), the rms over the samples of the inertial force vᵀ M q̈ against the
damping force vᵀ D q̇ and the rest vᵀ (A u - G - C q̇). At a ratio r of inertia to damping, an
error ε (relative) in the fitted damping or other forces there can be absorbed by an error of
about ε / r in the mass: at r = 8 %, 1 % becomes 12 %. Inputs reaching toward the corner
frequency raise r (RESULTS.md, challenge 3).
"""

from __future__ import annotations

import numpy as np

from softpinn.errors import UserError

__all__ = ["WEAK", "data_share", "inertial_share", "markdown_lines", "mostly", "sample_share",
           "weak_directions"]


def inertial_share(true_model, q, qd, u) -> dict[str, list[float]]:
    """Per eigen-direction of the true M(q) (smallest eigenvalue first): the median eigenvalue,
    the median corner frequency vᵀDv / (2π vᵀMv) [Hz], the rms over the samples of the
    inertial, damping and remaining forces along it, the ratio of inertia to damping, and
    ``vectors[i]``: the median |component| of the i-th eigenvector per coordinate.

    ``q``, ``qd`` (N, n) and ``u`` (N, m) are samples of a data set; q̈ is the true model's at
    them (eq. 6), so the numbers describe the motion the data hold, not any label noise.
    """
    q, qd, u = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, u))
    if not (len(q) == len(qd) == len(u)) or len(q) == 0:
        raise UserError(f"q, qd, u: expected the same number N > 0 of rows, got "
                         f"{len(q)}, {len(qd)}, {len(u)}")
    M = np.asarray(true_model.M(q))
    D = np.asarray(true_model.D(q))
    qdd = np.asarray(true_model.qdd(q, qd, u))
    lam, V = np.linalg.eigh(M)  # ascending: the lightest direction first
    inertial = np.einsum("nji,njk,nk->ni", V, M, qdd)
    damping = np.einsum("nji,njk,nk->ni", V, D, qd)
    # eq. 6 along v: vᵀ M q̈ + vᵀ D q̇ = vᵀ (A u - G - C q̇), so the rest is their sum
    rest = inertial + damping

    def rms(a):
        return np.sqrt(np.mean(a * a, axis=0))

    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = rms(inertial) / rms(damping)
        # the corner frequency (vᵀ D v) / (2π vᵀ M v): above it that direction moves by inertia,
        # below it by damping (and springs)
        corner = np.einsum("nji,njk,nki->ni", V, D, V) / (2 * np.pi * lam)
    return {"eigenvalue": np.median(lam, axis=0).tolist(),
            "corner_hz": np.median(corner, axis=0).tolist(),
            "inertial": rms(inertial).tolist(), "damping": rms(damping).tolist(),
            "rest": rms(rest).tolist(), "inertia_over_damping": ratio.tolist(),
            "vectors": np.median(np.abs(V), axis=0).T.tolist()}


def sample_share(true_model, samples) -> dict[str, list[float]] | None:
    """:func:`inertial_share` at :func:`bridge.analysis.analyze`'s ``samples`` ((q, q̇, u) or
    (q, q̇, u, meta); u None: no inputs); None where the true model is matrices already
    evaluated rather than a model with M, D and q̈."""
    if not all(callable(getattr(true_model, a, None)) for a in ("M", "D", "qdd")):
        return None
    q, qd, u = samples[:3]
    q = np.asarray(q, dtype=np.float64)
    if u is None:
        u = np.zeros((len(q), int(getattr(true_model, "m", 0) or 0)))
    return inertial_share(true_model, q, qd, u)


def data_share(true_model, data, trajectories=None, *, count: int = 2000,
               seed: int = 0) -> tuple[dict[str, list[float]], int]:
    """:func:`inertial_share` at up to ``count`` samples drawn (seeded) from the given
    trajectories of a data set (None: all; :func:`bridge.analysis.forces.data_samples`), and
    the number of samples drawn."""
    from softpinn.bridge.analysis.forces import data_samples

    q, qd, u, _ = data_samples(data, trajectories, count=count, seed=seed)
    return inertial_share(true_model, q, qd, u), len(q)


#: Below this ratio of inertial to damping forces a direction counts as weakly excited (task 5
#: with the paper's inputs, 8-9 %: M⁻¹ 6-22 % off; at 25 %: 1.2-1.7 %, RESULTS.md).
WEAK = 0.15


def weak_directions(share: dict) -> list[int]:
    """The 1-based directions whose inertia is under :data:`WEAK` of their damping."""
    return [i + 1 for i, r in enumerate(share["inertia_over_damping"])
            if r is not None and r < WEAK]


def mostly(vector, names=None) -> str:
    """The (at most two) coordinates a direction mostly moves: its components of at least 0.3,
    largest first, else its largest one (``names``: the coordinates' names, else q0, q1, ...)."""
    label = (lambda j: names[j]) if names is not None else (lambda j: f"q{j}")
    order = sorted(range(len(vector)), key=lambda j: -vector[j])
    return ", ".join(label(j) for j in order[:2] if vector[j] >= 0.3) or label(order[0])


def markdown_lines(share: dict, names=None, heading: str | None = "## What the data show of "
                   "the inertia") -> list[str]:
    """The share as a Markdown table, one row per direction (lightest first), and what it says."""
    lines = [heading, ""] if heading else []
    if not any(d for d in share["damping"] if d is not None and d == d):  # an undamped system
        return lines + ["The true model has no damping: there is no damping force to weigh the "
                        "inertia against (this comparison is for damped arms).", ""]
    lines += ["Along each eigenvector v of the true M(q), lightest first: the rms over the data's "
              "samples of the inertial force vᵀ M q̈ (the true q̈) against the damping force "
              "vᵀ D q̇, and the corner frequency vᵀDv / (2π vᵀMv). Where the inertia is a few "
              "percent of the damping the arm moves quasi-statically in that direction and the "
              "data fix its mass there (and M⁻¹, which the lightest directions dominate) only "
              "as well as the other forces are fitted.", "",
              "| direction | mostly | M eigenvalue | corner [Hz] | inertia | damping | "
              "inertia / damping |", "|---|---|---|---|---|---|---|"]
    for i, vec in enumerate(share["vectors"]):
        r = share["inertia_over_damping"][i]
        lines.append(f"| {i + 1} | {mostly(vec, names)} | {share['eigenvalue'][i]:.3g} | "
                     f"{share['corner_hz'][i]:.3g} | {share['inertial'][i]:.3g} | "
                     f"{share['damping'][i]:.3g} | {ratio_text(r)} |")
    weak = weak_directions(share)
    if weak:
        lines += ["", f"Weakly excited (inertia under {100 * WEAK:g} % of damping): direction"
                      f"{'s' if len(weak) > 1 else ''} {', '.join(map(str, weak))}."]
    return lines + [""]


def ratio_text(ratio) -> str:
    """A ratio in percent; "–" where it is undefined (no motion), "no damping" where infinite
    (a saved share holds both as None)."""
    if ratio is None or ratio != ratio:
        return "–"
    return "no damping" if ratio == float("inf") else f"{100 * ratio:.3g} %"
