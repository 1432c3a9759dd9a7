"""Progress bars of the command line (tqdm, on stderr), driven by the training callback: one
for the epochs of ``softpinn train`` (:class:`TrainBar`) and one for an L-BFGS finish
(:class:`LbfgsBar`)."""

from __future__ import annotations

import sys
import time


class LbfgsBar:
    """A second tqdm bar (stderr) for the L-BFGS finish of each trained group, which the epoch
    bars do not count: it shows the iterations done of ``lbfgs_steps``."""

    def __init__(self, disable: bool = False):
        self.disable, self.bar, self.key = disable, None, None

    def __call__(self, info: dict) -> None:
        from tqdm.auto import tqdm

        key = info["label"]
        if self.bar is None or key != self.key:
            self.close()
            self.bar = tqdm(total=info["lbfgs_steps"], file=sys.stderr, unit="it",
                            desc="L-BFGS", dynamic_ncols=True, leave=False,
                            disable=self.disable)
            self.key = key
        self.bar.update(max(0, int(info["lbfgs_done"]) - self.bar.n))
        post = {"train": f"{min(info['train_loss']):.3e}"}
        if info["test_loss"] is not None:
            post["test"] = f"{min(info['test_loss']):.3e}"
        self.bar.set_postfix(post, refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


class TrainBar:
    """tqdm progress bar (stderr) driven by the training callback; the L-BFGS finish gets a
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
        from tqdm.auto import tqdm

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

    def __call__(self, info: dict):
        if info["phase"] == "lbfgs" and info.get("lbfgs_done") is not None:
            self.lbfgs(info)
            return
        if self.bar is None:
            self.start()
        key = info["label"]
        prev = self.last.get(key, 0)
        if info["phase"] == "adamw":
            self.bar.update(max(0, info["epoch"] - prev))
            self.last[key] = info["epoch"]
            if self.compiling:
                self._started_training()
        te = info["test_loss"]
        post = {"seed": key, "train": f"{min(info['train_loss']):.3e}"}
        if self.compile_s is not None:
            post["compile"] = f"{self.compile_s:.1f}s"
        if te is not None:
            post["test"] = f"{min(te):.3e}"
        if info["phase"] != "adamw":
            post["phase"] = info["phase"]
        self.bar.set_postfix(post, refresh=False)

    def close(self):
        self.lbfgs.close()
        if self.bar is not None:
            if self.compiling:  # stopped before any epoch (an error): leave no bar behind
                self.bar.leave = False
            self.bar.close()
