"""Progress bars of the command line (tqdm, on stderr), drawn from the events of
:mod:`softpinn.progress`: the epochs of ``softpinn train`` (:class:`TrainBar`), an L-BFGS finish
(:class:`LbfgsBar`), one bar per model of ``softpinn reproduce`` (:class:`EpochBar`) or one over
the models running side by side (:class:`ModelsBar`), and a plain count (:class:`CountBar`:
simulated trajectories)."""

from __future__ import annotations

import sys
import time

from tqdm.auto import tqdm

from softpinn.progress import Progress, TrainProgress


def _losses(event: TrainProgress) -> dict[str, str]:
    post = {"train": f"{min(event.train_loss):.3e}"}
    if event.test_loss is not None:
        post["test"] = f"{min(event.test_loss):.3e}"
    return post


class CountBar:
    """A tqdm bar that follows the events' ``done`` (``total`` from the start); ``leave``
    after :meth:`close` only once :meth:`finished` (an error leaves one clean line)."""

    def __init__(self, total: int, desc: str, unit: str, *, disable: bool = False):
        self.bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=disable)

    def __call__(self, event: Progress) -> None:
        self.bar.update(max(0, event.done - self.bar.n))

    def close(self, *, failed: bool = False) -> None:
        self.bar.leave = not failed
        self.bar.close()


class LbfgsBar:
    """A second tqdm bar (stderr) for the L-BFGS finish of each trained group, which the epoch
    bars do not count: it shows the iterations done of the L-BFGS steps."""

    def __init__(self, disable: bool = False):
        self.disable, self.bar, self.key = disable, None, None

    def __call__(self, event: TrainProgress) -> None:
        key = event.label
        if self.bar is None or key != self.key:
            self.close()
            self.bar = tqdm(total=event.total, file=sys.stderr, unit="it",
                            desc="L-BFGS", dynamic_ncols=True, leave=False,
                            disable=self.disable)
            self.key = key
        self.bar.update(max(0, int(event.done) - self.bar.n))
        self.bar.set_postfix(_losses(event), refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


class TrainBar:
    """tqdm progress bar (stderr) driven by the training events; the L-BFGS finish gets a
    bar of its own (:class:`LbfgsBar`).

    :meth:`start` draws it before training starts, saying "compiling": the first epoch's call
    traces and compiles the programs (seconds to a minute). Once it returns, the bar says
    "training" and restarts its clock, so that its rate and ETA count training alone (the
    compile time is shown beside them)."""

    def __init__(self, total: int, disable: bool):
        self.total, self.disable = total, disable
        self.bar = None
        self.compiling = False
        self.compile_s = None
        self.last = {}
        self.lbfgs = LbfgsBar(disable)

    def start(self):
        # no AdamW epochs (epochs 0: L-BFGS alone): the L-BFGS bar is the only one
        self.bar = tqdm(total=self.total, file=sys.stderr, disable=self.disable or not self.total,
                        unit="epoch", dynamic_ncols=True, desc="compiling")
        self.compiling = True

    def _started_training(self):
        """The first epoch returned: restart the clock after the compile."""
        b = self.bar
        self.compiling = False
        if b.disable:
            return
        self.compile_s = time.time() - b.start_t
        b.set_description("training", refresh=False)
        b.initial = b.n
        b.start_t = b.last_print_t = time.time()
        b.last_print_n = b.n

    def __call__(self, event: TrainProgress):
        if event.phase == "lbfgs":
            self.lbfgs(event)
            return
        if self.bar is None:
            self.start()
        key = event.label
        prev = self.last.get(key, 0)
        if event.phase == "adamw":
            self.bar.update(max(0, event.epoch - prev))
            self.last[key] = event.epoch
            if self.compiling:
                self._started_training()
        post = {"seed": key, "train": f"{min(event.train_loss):.3e}"}
        if self.compile_s is not None:
            post["compile"] = f"{self.compile_s:.1f}s"
        if event.test_loss is not None:
            post["test"] = f"{min(event.test_loss):.3e}"
        if event.phase != "adamw":
            post["phase"] = event.phase
        self.bar.set_postfix(post, refresh=False)

    def close(self):
        self.lbfgs.close()
        if self.bar is not None:
            if self.compiling:  # stopped before any epoch (an error): leave no bar behind
                self.bar.leave = False
            self.bar.close()


class EpochBar:
    """One tqdm bar per trained model (``softpinn reproduce``), driven by the training events;
    with ``--jobs``, one bar over the models running side by side (:class:`ModelsBar`)."""

    def __init__(self):
        self.bar = None
        self.key = None
        self.lbfgs = LbfgsBar()
        self.models = None

    def __call__(self, event: Progress):
        if event.unit == "model" or getattr(event, "model", ""):  # models side by side
            if self.models is None:
                self.close()
                self.models = ModelsBar()
            self.models(event)
            return
        if event.phase == "lbfgs":
            self.lbfgs(event)
            return
        key = (event.label, event.epochs)
        if self.bar is None or key != self.key:
            self.close()
            self.bar = tqdm(total=event.epochs, file=sys.stderr, unit="epoch",
                            dynamic_ncols=True, leave=False)
            self.key = key
            self.last = 0
        if event.phase == "adamw":
            self.bar.update(max(0, event.epoch - self.last))
            self.last = event.epoch
        post = _losses(event)
        if event.phase != "adamw":
            post["phase"] = event.phase
        self.bar.set_postfix(post, refresh=False)

    def write(self, line: str) -> None:
        """A log line: above the models' bar while models run side by side, else after closing
        the model's bar."""
        if self.models is not None and not self.models.finished:
            self.models.write(line)
            return
        self.close()
        print(line, file=sys.stderr, flush=True)

    def close(self):
        self.lbfgs.close()
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        if self.models is not None:
            self.models.close()
            self.models = None


class ModelsBar:
    """``reproduce --jobs``: one bar over the models, and where each running one is."""

    def __init__(self):
        self.bar = None
        self.where: dict[str, str] = {}
        self.finished = False
        self.shown = 0.0

    def __call__(self, event: Progress) -> None:
        if event.unit == "model" and event.phase == "start":
            self.bar = tqdm(total=event.total, file=sys.stderr, unit="model",
                            dynamic_ncols=True, leave=False)
            return
        if self.bar is None:
            return
        done = event.unit == "model" and event.phase == "done"
        key = event.label if done else event.model
        if done:
            self.where.pop(key, None)
            self.bar.update(1)
            self.finished = self.bar.n >= self.bar.total
        elif event.phase == "lbfgs":
            self.where[key] = f"L-BFGS {event.done}/{event.total}"
        else:
            self.where[key] = f"{event.epoch}/{event.epochs} epochs"
        self.bar.set_postfix_str("; ".join(f"{k} {v}" for k, v in self.where.items()),
                                 refresh=False)
        now = time.monotonic()
        if now - self.shown >= 0.5 or done:  # at most twice a second
            self.bar.refresh()
            self.shown = now

    def write(self, line: str) -> None:
        tqdm.write(line, file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
