"""Matrix-equivalence fits: timings, and the paper's own Table I put through them.

Prints one JSON object:

* ``timings``: seconds per fit (best of 3) for N configurations of an n = 6, m = 6 system
  (Task 5's size), learned = P(q)^-1 true with a known smooth P(q), and the error of the
  recovered P;
* ``paper_table_I``: the paper's Task 4 Lagrangian matrices (Table I, three q, transcribed
  from the seed text below) through every transform: is the printed P equal to M M^-1, and
  how well does one P(q) map M^, D^, G^, A^ onto M, D, G, A at the printed precision?

Usage: ``python benchmarks/bench_bridge.py [--N 1000]``
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from softpinn.bridge.analysis.transforms import TRANSFORMS, fit_transform

# Table I (seed text), per q: true M, G, A (D = 0.1 I) and learned M^, D^, G^, A^, printed P.
TABLE_I = [
    {
        "q": [1.2, -0.2, 0.15],
        "M": [[1.728e-03, -3.121e-05, -1.957e-03], [-3.121e-05, 1.546e-03, 3.261e-04],
              [-1.957e-03, 3.261e-04, 9.286e-02]],
        "G": [1.293, -0.216, -1.149],
        "A": [[-0.037, -0.993, 0.065], [0.777, 0.037, -0.011], [0.0, 0.0, 0.771]],
        "M_hat": [[4.232e-3, 1.201e-3, -0.029], [1.201e-3, 5.990e-3, -0.015],
                  [-0.029, -0.015, 0.586]],
        "D_hat": [[0.161, -0.017, 0.004], [-0.017, 0.333, -0.008], [0.004, -0.008, 0.347]],
        "G_hat": [2.436, -0.612, -5.246],
        "A_hat": [[0.120, -1.715, -0.213], [3.049, -0.193, -0.126], [-0.343, 1.011, 3.396]],
        "P": [[0.611, -0.020, 0.0250], [-0.023, 0.280, 0.005], [0.330, 0.150, 0.246]],
    },
    {
        "q": [0.8, 0.2, 0.3],
        "M": [[3.639e-03, 4.518e-05, -1.936e-03], [4.518e-05, 3.470e-03, -4.841e-04],
              [-1.936e-03, -4.841e-04, 9.666e-02]],
        "G": [0.894, 0.223, -1.090],
        "A": [[0.026, -0.994, 0.064], [0.897, -0.026, 0.016], [0.0, 0.0, 0.890]],
        "M_hat": [[6.930e-3, 1.839e-3, -0.025], [1.839e-3, 0.012, -0.019],
                  [-0.025, -0.019, 0.503]],
        "D_hat": [[0.166, -0.008, -0.002], [-0.008, 0.327, -0.009], [-0.002, -0.009, 0.346]],
        "G_hat": [1.618, 0.813, -4.670],
        "A_hat": [[0.187, -1.655, -0.195], [2.970, -0.254, -0.126], [-0.401, 1.005, 3.425]],
        "P": [[0.623, -0.021, 0.027], [-0.018, 0.310, 0.011], [0.205, 0.095, 0.261]],
    },
    {
        "q": [-1.0, -0.6, 0.1],
        "M": [[1.245e-03, 5.786e-05, 1.406e-03], [5.786e-05, 1.183e-03, 8.435e-04],
              [1.406e-03, 8.435e-04, 9.342e-02]],
        "G": [-1.067, -0.640, -1.212],
        "A": [[0.093, -0.944, -0.047], [0.844, -0.093, -0.028], [0.0, 0.0, 0.788]],
        "M_hat": [[3.297e-03, 4.995e-04, -2.668e-02], [4.995e-04, 4.186e-03, -1.486e-02],
                  [-2.668e-02, -1.486e-02, 6.665e-01]],
        "D_hat": [[0.1821, -0.011, 0.003], [-0.0107, 0.312, 0.014], [0.003, 0.014, 0.341]],
        "G_hat": [-1.460, -1.894, -5.008],
        "A_hat": [[-0.119, -1.694, -0.108], [3.043, -0.097, -0.417], [-0.997, 0.601, 2.470]],
        "P": [[0.565, 0.038, 0.012], [0.042, 0.309, 0.012], [0.817, 0.307, 0.297]],
    },
]  # fmt: skip


def paper_table_i() -> dict:
    rows = TABLE_I
    q = np.array([r["q"] for r in rows])
    true = {
        "M": np.array([r["M"] for r in rows]),
        "D": np.broadcast_to(0.1 * np.eye(3), (3, 3, 3)).copy(),
        "G": np.array([r["G"] for r in rows]),
        "A": np.array([r["A"] for r in rows]),
    }
    learned = {k: np.array([r[f"{k}_hat"] for r in rows]) for k in ("M", "D", "G", "A")}
    printed = np.array([r["P"] for r in rows])
    out = {}
    for name in ("pointwise", "joint", "alpha", "constant", "direct"):
        res = fit_transform(name, true, learned, q)
        out[name] = {
            "residual": {k: round(v, 4) for k, v in res.residual.items()},
            "alpha": round(res.alpha, 4),
            "distance_from_alpha_I": round(res.distance_all, 4),
            "P_vs_printed_P": round(
                float(np.linalg.norm(res.P - printed) / np.linalg.norm(printed)), 4
            ),
        }
    # the printed P itself as a transform: residual of each matrix
    out["printed_P"] = {
        k: round(
            float(
                np.linalg.norm(printed @ (learned[k] if k != "G" else learned[k][..., None])
                               - (true[k] if k != "G" else true[k][..., None]))
                / np.linalg.norm(true[k])
            ),
            4,
        )
        for k in ("M", "D", "G", "A")
    }  # fmt: skip
    return out


def timings(N: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    n, m = 6, 6
    q = rng.uniform(-1, 1, (N, n))
    B = rng.standard_normal((N, n, n)) * 0.1 + np.eye(n)
    true = {
        "M": 1e-3 * B @ np.swapaxes(B, 1, 2),
        "D": np.broadcast_to(0.1 * np.eye(n), (N, n, n)).copy(),
        "G": np.sin(q),
        "A": np.eye(n)[None] + 0.1 * rng.standard_normal((N, n, m)),
    }
    W = rng.standard_normal((n, n, n)) * 0.1
    P = 2 * np.eye(n) + np.einsum("ni,ijk->njk", q, W)  # affine in q: in the degree-2 span
    Pinv = np.linalg.inv(P)
    learned = {k: Pinv @ v for k, v in true.items() if k != "G"}
    learned["G"] = (Pinv @ true["G"][..., None])[..., 0]
    out = {}
    for name in TRANSFORMS:
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            res = fit_transform(name, true, learned, q)
            best = min(best, time.perf_counter() - t0)
        out[name] = {
            "seconds": round(best, 5),
            "residual_total": float(f"{res.residual_total:.3g}"),
            "max_abs_P_error": float(f"{np.max(np.abs(res.P - P)):.3g}"),
        }
    return {"N": N, "n": n, "m": m, **out}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--N", type=int, default=1000)
    args = parser.parse_args()
    print(json.dumps({"timings": timings(args.N), "paper_table_I": paper_table_i()}, indent=1))


if __name__ == "__main__":
    main()
