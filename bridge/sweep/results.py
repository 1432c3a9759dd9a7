"""What a sweep writes on top of its trials' run directories: ``results.csv``, ``results.json``,
``results.md`` (every trial: settings, best test loss, epochs run, stopped early or not,
seconds), ``sweep.png`` (the best test loss against each swept setting) and the link ``best``
to the best trial's folder (:func:`write_results`, which returns the :class:`SweepResult`).
No Ray here: the rows are plain dicts (:mod:`.rows`)."""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from softpinn.bridge.base import outputs
from softpinn.bridge.sweep.config import SweepConfig
from softpinn.bridge.sweep.rows import trial_row
from softpinn.bridge.sweep.space import Random, dashed, format_value
from softpinn.learn import (
    TrainConfig,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    dataset_info,
)
from softpinn.learn.plots import SOFTWARE

FORMAT = "softpinn-sweep"
COLUMNS = ("trial", "seed", "best_test_loss", "epochs_run", "epochs", "stopped_early", "status",
           "seconds", "wall_seconds", "path")


@dataclass
class SweepResult:
    """What :func:`~softpinn.bridge.sweep.sweep` returns: the output folder, one row per trial
    (best first) and the best row (None if no trial reached a finite loss)."""

    out: Path
    rows: list[dict]
    best: dict | None

    @property
    def best_dir(self) -> Path | None:
        return None if self.best is None else self.out / self.best["path"]


def write_results(out: Path, trials, grid, finished, data, base_config: TrainConfig,
                  space: dict, config: SweepConfig) -> SweepResult:
    """Rank the trials (``grid``: trial name -> ``ray.tune.Result``; ``finished``: the names of
    those Tune finished) and write every results file into ``out``."""
    root = out.resolve()
    rows = rank([trial_row(t, grid.get(t.name), t.name in finished, root, config.scheduler)
                 for t in trials])
    ok = [r for r in rows if r["best_test_loss"] is not None]
    best = ok[0] if ok else None
    names = list(space)
    info = {
        "data": dataset_info(data),
        "model": base_config.model.kind,
        "base_config": base_config.to_dict(),
        "space": {k: (v.describe() if isinstance(v, Random) else v) for k, v in space.items()},
        "samples": config.samples,
        "seeds": config.seeds,
        "scheduler": config.scheduler,
        "metric": config.metric,
        "address": config.address,
        "trials": len(trials),
        "best": None if best is None else {
            "trial": best["trial"], "path": best["path"], "dir": str(root / best["path"]),
            "link": "best", "best_test_loss": best["best_test_loss"],
            "settings": best["settings"], "seed": best["seed"]},
    }
    written = [
        write_csv(out / "results.csv", rows, names),
        write_json(out / "results.json", rows, info),
        write_markdown(out / "results.md", rows, names, info),
        plot(out / "sweep.png", rows, space, config.metric.replace("_", " ")),
    ]
    link_best(out, best)
    outputs.record(out, [*written, *outputs.written_files(out / "tune")])
    return SweepResult(out=out, rows=rows, best=best)


def _loss(row) -> float:
    v = row.get("best_test_loss")
    return math.inf if v is None or not math.isfinite(v) else float(v)


def rank(rows: list[dict]) -> list[dict]:
    """The rows from the lowest best test loss up; trials without a finite loss last."""
    return sorted(rows, key=lambda r: (_loss(r), r["trial"]))


def write_csv(path: Path, rows: list[dict], names: list[str]) -> Path:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["trial", *names, *COLUMNS[1:]])
    for r in rows:
        w.writerow([r["trial"], *(_cell(r["settings"].get(n)) for n in names),
                    *(_cell(r.get(c)) for c in COLUMNS[1:])])
    return atomic_write_text(path, buf.getvalue())


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ""
    return str(v)


def _md_loss(v) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v:.3e}"


def write_markdown(path: Path, rows: list[dict], names: list[str], info: dict) -> Path:
    best = info.get("best")
    lines = [f"# Sweep: {info['trials']} trials on {Path(info['data']['path']).name}", ""]
    counts = {}
    for r in rows:
        key = "stopped early" if r["stopped_early"] else r["status"].split(":")[0]
        counts[key] = counts.get(key, 0) + 1
    lines.append(
        f"{info['model']} model; swept: "
        + (", ".join(f"{dashed(k)} {v}" for k, v in info["space"].items()) or "seeds only")
        + f"; {info['seeds']} seed(s) per combination; scheduler {info['scheduler']} on "
        f"{info['metric'].replace('_', ' ')}. "
        + ", ".join(f"{n} {k}" for k, n in counts.items()) + "."
    )
    lines.append("")
    if best is not None:
        lines.append(
            f"**Best:** [{best['path']}]({best['path']}/) (linked as [best](best/)), "
            f"best test loss {_md_loss(best['best_test_loss'])}"
            + "".join(f", {dashed(k)} = {format_value(v)}" for k, v in best["settings"].items())
            + f", seed {best['seed']}."
        )
    else:
        lines.append("**No trial finished with a finite test loss.**")
    lines += ["", "![best test loss against the swept settings](sweep.png)", ""]
    head = ["#", "trial", *(dashed(n) for n in names), "seed", "best test loss", "epochs",
            "stopped early", "status", "seconds"]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "|".join("---" for _ in head) + "|")
    for i, r in enumerate(rows, 1):
        cells = [str(i), f"[{r['trial']}]({r['path']}/)" if r.get("path") else r["trial"],
                 *(format_value(r["settings"].get(n)) for n in names), str(r["seed"]),
                 _md_loss(r["best_test_loss"]),
                 "–" if r["epochs_run"] is None else f"{r['epochs_run']} / {r['epochs']}",
                 "yes" if r["stopped_early"] else "no", r["status"].replace("|", "/"),
                 "–" if r["wall_seconds"] is None else f"{r['wall_seconds']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    groups = _by_combination(rows, names)
    if info["seeds"] > 1 and groups:
        lines += ["", "## Mean over seeds", ""]
        head = [*(dashed(n) for n in names), "seeds", "best test loss (mean ± std)"]
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + "|".join("---" for _ in head) + "|")
        for key, losses in sorted(groups.items(), key=lambda kv: np.mean(kv[1])):
            lines.append("| " + " | ".join([*(format_value(v) for v in key), str(len(losses)),
                                            f"{np.mean(losses):.3e} ± {np.std(losses):.1e}"])
                         + " |")
    lines += ["", "Every trial is a run directory of `softpinn train`: `softpinn predict "
              "best DATA.npz --horizon S`, `softpinn analyze`, `softpinn train --resume` work "
              "on it. Stopped early: the scheduler ended the trial at a rung where its loss was "
              "among the worse; its folder holds the best model it reached.", ""]
    return atomic_write_text(path, "\n".join(lines))


def _by_combination(rows, names) -> dict[tuple, list[float]]:
    groups: dict[tuple, list[float]] = {}
    for r in rows:
        if math.isfinite(_loss(r)):
            key = tuple(r["settings"].get(n) for n in names if n != "seed")
            groups.setdefault(key, []).append(_loss(r))
    return groups


def write_json(path: Path, rows: list[dict], info: dict) -> Path:
    return atomic_write_json(path, {"format": FORMAT, "version": 1, **info, "results": rows})


def link_best(out: Path, best: dict | None) -> Path | None:
    """``OUT/best`` -> ``trials/<name>`` (relative, so the folder may move); a previous link is
    replaced, anything else named ``best`` is left alone (and no link made)."""
    link = out / "best"
    if link.is_symlink():
        link.unlink()
    elif link.exists():
        return None
    if best is None or not best.get("path"):
        return None
    try:
        os.symlink(best["path"], link, target_is_directory=True)
    except OSError:  # no symlinks here: results.md and results.json name the folder
        return None
    return link


def _numeric(values) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def plot(path: Path, rows: list[dict], space: dict, metric_label: str) -> Path:
    """One panel per swept setting (or per seed when only seeds vary): every trial's best test
    loss (log scale) against the setting's value (log scale too, but for a uniform or int range,
    a seed, values <= 0 and named choices); stopped trials hollow, the best one a star."""
    # matplotlib only when a sweep draws (``import softpinn.bridge.sweep`` stays light)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = list(space) or ["seed"]
    cols = min(3, len(names))
    nrows = -(-len(names) // cols)
    fig = Figure(figsize=(4.2 * cols, 3.4 * nrows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, cols, squeeze=False).ravel()
    ok = [r for r in rows if math.isfinite(_loss(r))]
    best = min(ok, key=_loss) if ok else None
    for ax, name in zip(axes, names, strict=False):
        values = [r["settings"].get(name, r["seed"]) if name != "seed" else r["seed"]
                  for r in ok]
        if _numeric(values) and values:
            xs = np.asarray(values, dtype=float)
            rng = space.get(name)
            positive = bool(np.all(xs > 0))
            linear = isinstance(rng, Random) and rng.kind in ("uniform", "int")
            if positive and name != "seed" and not linear:
                ax.set_xscale("log")
        else:
            labels = sorted({format_value(v) for v in values})
            xs = np.asarray([labels.index(format_value(v)) for v in values], dtype=float)
            ax.set_xticks(range(len(labels)), labels)
        ys = np.asarray([_loss(r) for r in ok])
        stopped = np.asarray([r["stopped_early"] for r in ok], dtype=bool)
        if (~stopped).any():
            ax.scatter(xs[~stopped], ys[~stopped], s=30, color="C0", label="ran to the end")
        if stopped.any():
            ax.scatter(xs[stopped], ys[stopped], s=30, facecolors="none", edgecolors="C1",
                       label="stopped early")
        if best is not None:
            i = ok.index(best)
            ax.scatter([xs[i]], [ys[i]], s=160, marker="*", color="C3", zorder=3,
                       label="best")
        ax.set_yscale("log")
        ax.margins(x=0.12, y=0.15)  # the best trial's star is not cut at the edge
        ax.set_xlabel(dashed(name))
        ax.set_ylabel(metric_label)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    if ok:
        axes[0].legend(fontsize="small")
    else:
        axes[0].text(0.5, 0.5, "no trial with a finite loss", ha="center",
                     transform=axes[0].transAxes)
    fig.suptitle(f"sweep: {len(rows)} trials")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, metadata={"Software": SOFTWARE})
    return atomic_write_bytes(path, buf.getvalue())
