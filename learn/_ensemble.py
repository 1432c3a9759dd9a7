"""The ensemble engine: K seeds trained as one stacked model (or one after another), with
checkpoints, NaN rollback, deferred interrupts (Ctrl-C finishes the epoch and saves) and early
stopping; :func:`finish_member` writes each member's model, history and metrics."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from softpinn.errors import NonFiniteStart, TrainingDiverged, UserError
from softpinn.learn import _checkpoint as ckpt
from softpinn.learn._init_model import initial_model
from softpinn.learn._members import select_members, stack, unstack
from softpinn.learn._models import make_model
from softpinn.learn._objective import note_range, range_metrics, rollout_stage
from softpinn.learn._programs import Programs
from softpinn.learn._rundir import loss_plot, member_dir
from softpinn.learn._stop import Stop, StopReason
from softpinn.progress import TrainProgress


@dataclass
class MemberResult:
    """The outcome of one seed: its run directory, best model and figures."""

    seed: int
    run_dir: Path
    model: Any
    metrics: dict
    history: list[dict] = field(repr=False)


# ---------------------------------------------------------------------------------- engine


class DeferredInterrupt:
    """While training, the first Ctrl-C (SIGINT) lets the current epoch finish, then the loop
    saves a checkpoint and raises KeyboardInterrupt; a second one interrupts at once. Only in the
    main thread (elsewhere signal handlers cannot be set, and Ctrl-C raises as usual)."""

    def __init__(self):
        self.requested = False
        self._old = None

    def _handler(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self):
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            try:
                self._old = signal.signal(signal.SIGINT, self._handler)
            except (ValueError, OSError):
                self._old = None
        return self

    def __exit__(self, *exc):
        import signal

        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
        return False


class MemberGroup:
    """K members trained together as one stacked model (K = 1 for a single run)."""

    def __init__(self, prog: Programs, seeds, ckpt_path: Path, header_base: dict,
                 test_eval: Callable | None = None):
        # prog.eval_fn: the loss that picks (validation's, if any); test_eval: then test's, noted
        self.prog = prog
        self.test_eval = test_eval
        self.seeds = list(seeds)
        self.K = len(self.seeds)
        self.ckpt_path = ckpt_path
        self.header_base = header_base
        cfg = prog.config
        if cfg.init is not None:
            models = [initial_model(cfg.init, cfg.model)] * self.K
        else:
            models = [make_model(cfg.model, key=jax.random.PRNGKey(s)) for s in self.seeds]
        self.params = stack([eqx.filter(m, eqx.is_array) for m in models])
        self.opt_state = prog.init_opt(self.params)
        self.best = self.params
        self.keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(s), 1) for s in self.seeds])
        self.epoch = 0  # epochs completed
        self.best_loss = np.full(self.K, np.inf)
        self.best_epoch = np.zeros(self.K, dtype=int)
        self.best_test = np.full(self.K, np.nan)  # the test loss at best_epoch (validation)
        self.bad = np.zeros(self.K, dtype=int)
        self.over = np.zeros(self.K, dtype=int)  # evaluations in a row above overfit x best
        self.active = np.ones(self.K, dtype=bool)
        self.stops = [Stop(StopReason.RUNNING, "running")] * self.K
        self.history: list[list[dict]] = [[] for _ in range(self.K)]
        self.seconds = 0.0
        self.adam_done = False
        self.lbfgs_done = 0

    # -- checkpoint
    def _tree(self):
        return (self.params, self.opt_state, self.best)

    def header(self) -> dict:
        return {
            **self.header_base,
            "seeds": self.seeds,
            "epoch": self.epoch,
            "best_loss": [float(x) for x in self.best_loss],
            "best_epoch": self.best_epoch.tolist(),
            **({"best_test": self.best_test.tolist()} if self.test_eval else {}),
            "bad": self.bad.tolist(),
            "over": self.over.tolist(),
            "active": self.active.tolist(),
            "stopped": [s.detail for s in self.stops],
            "stop_reason": [s.reason.value for s in self.stops],
            "history": self.history,
            "seconds": self.seconds, "adam_done": self.adam_done, "lbfgs_done": self.lbfgs_done,
        }

    def save(self):
        ckpt.save_tree(self.ckpt_path, self._tree(), self.header(), record=True)

    def restore(self):
        header, tree = ckpt.load_tree(self.ckpt_path, self._tree())
        if header.get("seeds") != self.seeds:
            raise UserError(
                f"{self.ckpt_path}: checkpoint holds seeds {header.get('seeds')}, "
                f"expected {self.seeds}"
            )
        self.params, self.opt_state, self.best = tree
        self.epoch = int(header["epoch"])
        self.best_loss = np.array(header["best_loss"], dtype=float)
        self.best_epoch = np.array(header["best_epoch"], dtype=int)
        self.best_test = np.array(header.get("best_test", [np.nan] * self.K), dtype=float)
        self.bad = np.array(header["bad"], dtype=int)
        self.over = np.array(header.get("over", [0] * self.K), dtype=int)
        self.active = np.array(header["active"], dtype=bool)
        self.stops = Stop.read_all(header)
        self.history = header["history"]
        self.seconds = float(header["seconds"])
        self.adam_done = bool(header["adam_done"])
        self.lbfgs_done = int(header["lbfgs_done"])
        self._reopen()

    def _reopen(self):
        """A resumed run asked for more epochs than it finished: the members that completed
        their epochs train on (early-stopped and diverged ones stay stopped)."""
        cfg = self.prog.config
        if not (self.adam_done and self.epoch < cfg.epochs):
            return
        done = [k for k in range(self.K) if self.stops[k].reason is StopReason.COMPLETED]
        if not done:
            return
        if self.lbfgs_done:
            raise UserError(
                f"epochs: the run in {self.ckpt_path.parent} ended with {self.lbfgs_done} L-BFGS "
                f"iterations after {self.epoch} epochs; AdamW cannot continue after them "
                "(train a new run for more epochs)"
            )
        for k in done:
            self.active[k] = True
            self.stops[k] = Stop(StopReason.RUNNING, "running")
        self.adam_done = False

    @property
    def finished(self) -> bool:
        return self.adam_done and self.lbfgs_done >= self.prog.config.lbfgs_steps

    # -- bookkeeping shared by both phases
    def _record(self, epoch, train_loss, test_loss, phase, evaluate, params_prev, opt_prev):
        """Update best/patience/history after a step; roll back diverged members.
        ``test_loss``: the loss that picks (validation, where the run has it)."""
        cfg = self.prog.config
        info = (np.asarray(self.test_eval(self.params), dtype=float)
                if evaluate and self.test_eval is not None else None)
        was_active = self.active.copy()
        train_loss = np.asarray(train_loss, dtype=float)
        test_loss = np.asarray(test_loss, dtype=float) if evaluate else None
        bad_now = self.active & ~np.isfinite(train_loss)
        if test_loss is not None:
            bad_now |= self.active & ~np.isfinite(test_loss)
        if bad_now.any():
            mask = jnp.asarray(bad_now)
            self.params = select_members(mask, params_prev, self.params)
            self.opt_state = select_members(mask, opt_prev, self.opt_state)
            for k in np.flatnonzero(bad_now):
                self.stops[k] = Stop(StopReason.DIVERGED, f"diverged at epoch {epoch} ({phase})")
            self.active = self.active & ~bad_now
        if test_loss is not None:
            improved = self.active & (test_loss < self.best_loss)
            if improved.any():
                self.best = select_members(jnp.asarray(improved), self.params, self.best)
            self.best_loss = np.where(improved, test_loss, self.best_loss)
            self.best_epoch = np.where(improved, epoch, self.best_epoch)
            if info is not None:
                self.best_test = np.where(improved, info, self.best_test)
            if phase == "adamw":
                self.bad = np.where(improved, 0, self.bad + self.active)
                if cfg.patience is not None:
                    out = self.active & (self.bad >= cfg.patience)
                    for k in np.flatnonzero(out):
                        self.stops[k] = Stop(StopReason.PATIENCE, f"early stop at epoch {epoch} "
                                             f"(patience {cfg.patience})")
                    self.active = self.active & ~out
                if cfg.overfit is not None:
                    above = self.active & (test_loss > cfg.overfit * self.best_loss)
                    self.over = np.where(above, self.over + 1, 0)
                    out = self.active & (self.over >= cfg.overfit_evals)
                    for k in np.flatnonzero(out):
                        self.stops[k] = Stop(StopReason.OVERFIT, (
                            f"early stop at epoch {epoch} (overfit: test loss above "
                            f"{cfg.overfit:g}x its best, {self.best_loss[k]:.4g} at epoch "
                            f"{self.best_epoch[k]}, for {cfg.overfit_evals} evaluations)"))
                    self.active = self.active & ~out
            if cfg.target_loss is not None:
                out = self.active & (test_loss <= cfg.target_loss)
                for k in np.flatnonzero(out):
                    self.stops[k] = Stop(StopReason.TARGET, (
                        f"reached test loss {test_loss[k]:.4g} <= {cfg.target_loss:g} at "
                        f"epoch {epoch} ({phase})"))
                self.active = self.active & ~out
        for k in range(self.K):
            if bad_now[k] or not was_active[k]:
                continue
            if test_loss is not None:
                held = ({"test_loss": float(test_loss[k])} if info is None else
                        {"test_loss": float(info[k]), "validation_loss": float(test_loss[k])})
                self.history[k].append({"epoch": int(epoch), "train_loss": float(train_loss[k]),
                                        **held, "seconds": round(self.seconds, 3),
                                        "phase": phase})
        return bad_now

    def run(self, progress: Callable | None, label: str):
        with DeferredInterrupt() as stop:
            self._run(progress, label, stop)

    def _run(self, progress, label, stop):
        cfg = self.prog.config
        prog = self.prog
        t_last = time.perf_counter()
        self.consistent = True
        try:
            if self.epoch == 0 and not any(self.history):
                # epoch 0: the untrained model, on the full training and test sets
                tr0 = np.asarray(prog.eval_train_fn(self.params))
                te0 = np.asarray(prog.eval_fn(self.params))
                bad0 = self._record(0, tr0, te0, "adamw", True, self.params, self.opt_state)
                if bad0.any():
                    raise NonFiniteStart(self._non_finite_start_message(tr0, te0, bad0))
                if progress is not None:
                    progress(self._progress_info(label, 0, tr0, te0, "adamw"))
            while not self.adam_done and self.epoch < cfg.epochs and self.active.any():
                if stop.requested:
                    raise KeyboardInterrupt
                e = self.epoch + 1
                prev_p, prev_s = self.params, self.opt_state
                new_p, new_s, tr, out_of_range = prog.epoch_step(  # rollout_schedule's stage
                    self.params, self.opt_state, self.keys, self.epoch, jnp.asarray(self.active),
                    horizon=rollout_stage(cfg, e))
                evaluate = e % cfg.eval_every == 0 or e == cfg.epochs
                te = prog.eval_fn(new_p) if evaluate else None
                tr = np.asarray(tr)
                te = None if te is None else np.asarray(te)
                now = time.perf_counter()
                # commit the epoch: the state is inconsistent until epoch = e
                self.consistent = False
                self.seconds += now - t_last
                t_last = now
                self.params, self.opt_state = new_p, new_s
                bad_now = self._record(e, tr, te, "adamw", evaluate, prev_p, prev_s)
                note_range(self.history, e, rollout_stage(cfg, e), out_of_range)
                self.epoch = e
                self.consistent = True
                if bad_now.any():
                    self.save()
                    raise TrainingDiverged(self._diverged_message())
                if progress is not None:
                    progress(self._progress_info(label, e, tr, te, "adamw"))
                if e % cfg.checkpoint_every == 0:
                    self.save()
            if not self.adam_done:
                for k in range(self.K):
                    if self.stops[k].reason is StopReason.RUNNING:
                        self.stops[k] = Stop(StopReason.COMPLETED,
                                             f"completed {self.epoch} epochs")
                self.adam_done = True
                self.save()
            if cfg.lbfgs_steps > self.lbfgs_done:
                self._run_lbfgs(progress, label, stop)
        except KeyboardInterrupt:
            # save the last completed epoch; a second Ctrl-C in the middle of committing one
            # leaves the previous checkpoint on disk
            if self.consistent:
                self.save()
            raise

    def _run_lbfgs(self, progress, label, stop):
        cfg, prog = self.prog.config, self.prog
        # an interrupted L-BFGS phase restarts from the best parameters so far
        self.history = [[r for r in h if r["phase"] != "lbfgs"] for h in self.history]
        # start from the best AdamW parameters of every member that did not diverge or reach
        # the target test loss already
        ok = np.array([s.reason not in (StopReason.DIVERGED, StopReason.TARGET)
                       for s in self.stops])
        self.params = self.best
        state = prog.lbfgs_init(self.params)
        active = ok.copy()
        t_last = time.perf_counter()
        done = 0
        while done < cfg.lbfgs_steps and active.any():
            if stop.requested:
                raise KeyboardInterrupt
            prev_p = self.params
            self.params, state, tr = prog.lbfgs_fn(self.params, state, jnp.asarray(active))
            done += cfg.lbfgs_chunk
            te = np.asarray(prog.eval_fn(self.params))
            tr = np.asarray(tr)
            now = time.perf_counter()
            self.seconds += now - t_last
            t_last = now
            self.active = active
            epoch = self.epoch + done // cfg.lbfgs_chunk
            self._record(epoch, tr, te, "lbfgs", True, prev_p, prev_p)
            active = self.active.copy()  # less the diverged and those at the target loss
            if progress is not None:
                progress(self._progress_info(label, epoch, tr, te, "lbfgs", lbfgs_done=done))
        self.active = np.zeros(self.K, dtype=bool)
        self.lbfgs_done = cfg.lbfgs_steps
        self.save()

    def _diverged_message(self) -> str:
        which = [f"seed {s}: {st.detail}" for s, st in zip(self.seeds, self.stops, strict=True)
                 if st.reason is StopReason.DIVERGED]
        return (
            f"training stopped: the loss became NaN/inf ({'; '.join(which)}); "
            f"the last good checkpoint is kept in {self.ckpt_path.parent}; "
            "try a smaller lr, or float64 if the model is float32"
        )

    def _non_finite_start_message(self, tr0, te0, bad0) -> str:
        which = [f"seed {s}: train loss {tr0[k]:.3g}, test loss {te0[k]:.3g}"
                 for k, s in enumerate(self.seeds) if bad0[k]]
        return (
            "training cannot start: the untrained model's loss is not finite "
            f"({'; '.join(which)}); "
            "check the data's scale (values near 1e150 or more overflow the loss) and the model "
            "settings (eps, mass_init)"
        )

    def _progress_info(self, label, epoch, tr, te, phase, lbfgs_done=None) -> TrainProgress:
        cfg = self.prog.config
        lbfgs = phase == "lbfgs"
        return TrainProgress(
            done=int(lbfgs_done if lbfgs else epoch),
            total=cfg.lbfgs_steps if lbfgs else cfg.epochs,
            unit="iteration" if lbfgs else "epoch",
            label=label,
            phase=phase,
            epoch=int(epoch),
            epochs=cfg.epochs,
            seeds=tuple(int(s) for s in self.seeds),
            train_loss=tuple(float(x) for x in tr),
            test_loss=None if te is None else tuple(float(x) for x in te),
            best_test_loss=tuple(float(x) for x in self.best_loss),
            active=tuple(bool(a) for a in self.active),
            seconds=float(self.seconds),
        )

    def member_model(self, k: int):
        return eqx.combine(unstack(self.best, k), self.prog.static)


def finish_member(g: MemberGroup, k, seed, run_dir, K, n_train, n_test, *,
                  interrupted: bool = False) -> MemberResult:
    """Write member k's best model, history and metrics; ``interrupted``: the run stops here
    on Ctrl-C, and a member still training says so ("interrupted at epoch E")."""
    mdir = member_dir(run_dir, seed, K)
    model = g.member_model(k)
    hist = g.history[k]
    last = hist[-1] if hist else {"train_loss": float("nan"), "test_loss": float("nan")}
    picked = {"best_test_loss": float(g.best_loss[k])} if g.test_eval is None else {
        "best_test_loss": float(g.best_test[k]), "best_validation_loss": float(g.best_loss[k])}
    metrics = {
        "seed": seed,
        **picked,  # with validation: the kept model's test loss, and its validation loss
        "best_epoch": int(g.best_epoch[k]),
        "final_train_loss": last["train_loss"],
        "final_test_loss": last["test_loss"],
        "epochs_run": int(g.epoch),
        "lbfgs_steps": int(g.lbfgs_done),
        "stopped": g.stops[k].detail,
        "stop_reason": g.stops[k].reason.value,
        "seconds": round(g.seconds, 3),
        "train_pairs": n_train,
        "test_pairs": n_test,
        **range_metrics(hist),
    }
    if interrupted and g.stops[k].reason is StopReason.RUNNING:
        lbfgs = f" + {int(g.lbfgs_done)} L-BFGS iterations" if g.lbfgs_done else ""
        metrics["stopped"] = f"interrupted at epoch {int(g.epoch)}{lbfgs} (--resume continues)"
        metrics["stop_reason"] = StopReason.INTERRUPTED.value
    ckpt.save_tree(mdir / "model.eqx", eqx.filter(model, eqx.is_array), {"seed": seed},
                   record=True)
    ckpt.write_history(mdir / "history.csv", hist, record=True)
    ckpt.atomic_write_json(mdir / "metrics.json", metrics, record=True)
    loss_plot(mdir, [hist], None)
    return MemberResult(seed=seed, run_dir=mdir, model=model, metrics=metrics, history=hist)

