"""``report.md`` of a control comparison: the setting, one table per reference, the figures;
the controllers that failed (each with its error in one line), the causes of failed solves and
what a failed solve applies instead (issue 46)."""

from __future__ import annotations

from pathlib import Path

from softpinn.files import atomic_write

__all__ = ["write_report"]


def _num(v, fmt=".3g"):
    return "n/a" if v is None else format(v, fmt)


def _outside_lines(per: dict) -> list[str]:
    """A sentence on the learned models whose arm left the configurations of their training
    data (none when no controller has a data range)."""
    checked = {name: m["outside_data"] for name, m in per.items() if m.get("outside_data")}
    if not checked:
        return []
    margin = next(iter(checked.values()))["margin"]
    left = [f"{name} from {o['first_s']:.2f} s, {o['steps']} steps ({', '.join(o['coordinates'])})"
            for name, o in checked.items() if o["steps"]]
    if not left:
        return [f"Every learned model's arm stayed within its training data's configurations "
                f"(each q within the range of its training trajectories, ± {100 * margin:g} % "
                "of that range).", ""]
    return ["**Outside the training data**: the arm left the configurations the model was "
            f"trained on (some q beyond its training trajectories' range by more than "
            f"{100 * margin:g} % of that range), where its predictions are not backed by data: "
            + "; ".join(left) + ".", ""]


def _failure_lines(result: dict) -> list[str]:
    """The run's end (interrupted), the controllers that failed, the failed solves' causes."""
    lines = []
    if result.get("interrupted"):
        lines += ["**Interrupted** (Ctrl-C): only the controllers and references that finished "
                  "are below; no figures were drawn.", ""]
    for name, f in (result.get("failed") or {}).items():
        where = "building its MPC" if f["stage"] == "build" else f"on the {f['stage']} reference"
        lines.append(f"**{name} failed** {where}: {f['error']}" + (
            " (its traceback: results.json, failed)" if f.get("traceback") else ""))
    if result.get("failed"):
        lines.append("")
    failed = [(r, n, m) for r, per in result["results"].items() for n, m in per.items()
              if m.get("failures")]
    if failed:
        lines += ["**Failed solves** by cause (infeasible, iteration limit, numerical: "
                  "results.json's failure_causes; the solvers' statuses: failure_statuses): "
                  + "; ".join(f"{n} on {r}: " + ", ".join(
                      f"{k} {c}" for c, k in (m.get("failure_causes") or {}).items())
                      for r, n, m in failed) + ". " + _sentence(result.get("fallback")), ""]
    return lines


def _sentence(text) -> str:
    return "" if not text else text[0].upper() + text[1:] + "."


def write_report(path, result: dict, figures: list[str]) -> Path:
    """Write the report for ``result`` (what :func:`~.compare.compare` returns) to ``path``."""
    path = Path(path)
    cfg = result["config"]
    unit = result["output"]["unit"]
    def vec(v):
        if v is None:
            return "none"
        return "[" + ", ".join("unbounded" if x is None else f"{x:.4g}" for x in v) + "]"

    bounds = ("none" if cfg["u_min"] is None and cfg["u_max"] is None
              else f"u_min {vec(cfg['u_min'])}, u_max {vec(cfg['u_max'])}")
    lines = [
        f"# Model-predictive control of {result['model']}",
        "",
        f"The plant is the true model ({result['plant']['integrator']}, rtol "
        f"{result['plant']['rtol']:g}), fed back {result['plant']['feedback']}; each controller "
        f"predicts with its own model. MPC at {result['rate']:g} Hz (dt {cfg['dt']:g} s), horizon "
        f"{cfg['horizon']} ({cfg['horizon'] * cfg['dt']:g} s), RK4 with at least "
        f"{cfg['substeps']} sub-step(s) per step, solver {cfg['solver']}"
        + (f" (Gauss-Newton SQP, QP {cfg['qpsol']}, "
           + ("one iteration per step: the real-time iteration)" if cfg["max_iter"] == 1
              else f"at most {cfg['max_iter']} iterations)")
           + (", frozen sensitivities: one Jacobian of the model per step, an iteration that "
              "gives no step redone with the exact ones (column 'iterations': how many)"
              if cfg.get("sensitivities") == "frozen" else "")
           + (", lifted sensitivities: each step linearised about the last plan's predicted "
              "states (no rollout before the line search), one Jacobian of the model per "
              "step; a step that fails is redone from a rollout, then with exact "
              "sensitivities (column 'iterations': how many of each)"
              if cfg.get("sensitivities") == "lifted" else "")
           if cfg["solver"] == "sqp" else f" (at most {cfg['max_iter']} iterations)")
        + f"; weights: output {cfg['weight_y']:g}, input {cfg['weight_u']:g}, input change "
        f"{cfg['weight_du']:g}; input bounds: {bounds}"
        + (f"; offset-free: a constant state disturbance estimated with gain "
           f"{cfg['offset_free']:g} from each step's prediction error is added to every "
           "predicted step, starting from the model's miss at the rest state where a loop "
           "starts at rest (results.json: at_rest)"
           + (f", and its change per step estimated with gain {cfg['offset_free_rate']:g} "
              "(an alpha-beta filter: the estimate follows an error that drifts from step to "
              "step, and stays constant over each horizon)"
              if cfg.get("offset_free_rate") else "")
           if cfg.get("offset_free") else "") + ".",
        "",
        f"Output: {result['output']['what']} ({', '.join(result['output']['components'])}, "
        f"{unit}). Machine: {result['machine']}"
        + (f", load average {result['load_average'][1]:g} over the last 5 minutes (solve times "
           "grow when it exceeds the cores)" if result.get("load_average") else "")
        + f". CasADi {result['casadi']}, softpinn {result['softpinn']}. Wall time "
        f"{result['seconds']:.1f} s.",
        "",
        *_failure_lines(result),
        "## Controllers",
        "",
        "| controller | source | RK4 sub-steps | compiled C | build [s] |",
        "|---|---|---|---|---|",
    ]
    for name, c in result["controllers"].items():
        src = c.get("run") or c.get("source")
        if c.get("source") == "linearised":
            src = "true model linearised at the centre's equilibrium"
        elif c.get("source") == "true":
            src = "true model (best case)"
        build = (c.get("build_seconds") or 0.0) + (c.get("export_seconds") or 0.0)
        lines.append(f"| {name} | {src} | {c.get('substeps')} | "
                     f"{'yes' if c.get('compiled') else 'no'} | {build:.1f} |")
    for rname, per in result["results"].items():
        ref = result["references"][rname]
        extra = (f"period {ref['period']:g} s" if ref["kind"] == "circle"
                 else f"each target held {ref['hold']:g} s")
        lines += [
            "",
            f"## Reference: {rname}",
            "",
            f"{ref['kind']} of radius {ref['radius']:g} in q's first two coordinates around q = "
            f"{[round(v, 4) for v in ref['center']]}, {extra}; {ref['duration']:g} s "
            f"({ref['steps']} steps), starting at rest at q = "
            f"{[round(v, 4) for v in ref['q0']]}.",
            "",
            f"| controller | error RMS [{unit}] | error max [{unit}] | final [{unit}] | "
            "input RMS | input change RMS | failures | iterations | solve mean [ms] | "
            "p95 [ms] | max [ms] |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for name, m in per.items():
            fail = f"{m['failures']}/{m['steps']}" + (" diverged" if m["diverged"] else "")
            fail += "".join(f", {k} {c}" for c, k in (m.get("failure_causes") or {}).items())
            its = _num(m["iterations_mean"], ".2g") + (
                f" ({m['exact_iterations']} exact)" if cfg.get("sensitivities") == "frozen"
                else f" ({m['lifted_iterations']} lifted, {m['exact_iterations']} exact)"
                if cfg.get("sensitivities") == "lifted" else "")
            lines.append(
                f"| {name} | {_num(m['error_rms'])} | {_num(m['error_max'])} | "
                f"{_num(m['error_final'])} | {_num(m['effort_rms'])} | "
                f"{_num(m['effort_rate_rms'])} | {fail} | {its} | "
                f"{_num(m['solve_ms_mean'], '.2f')} | {_num(m['solve_ms_p95'], '.2f')} | "
                f"{_num(m['solve_ms_max'], '.2f')} |")
        lines += ["", *_outside_lines(per)]
        lines.append("")
        for f in figures:
            if f.endswith(f"_{rname}.png"):
                lines.append(f"![{Path(f).stem}]({f})")
    lines += ["", "Time series: `traces/<reference>.npz`; all numbers: `results.json`.", ""]
    return atomic_write(path, "\n".join(lines))
