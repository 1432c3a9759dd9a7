"""`softpinn derive` derives once: the Functions it writes wrap the model it derived and timed."""

from __future__ import annotations

import importlib
import json

from softpinn.bridge.cli import main

eom = importlib.import_module("softpinn.symbolic.derivation._eom")
# the module, not the function ``functions`` that shadows it as an attribute
functions_mod = importlib.import_module("softpinn.symbolic.model._functions")
# the command's own reference, taken from the symbolic face when its module loaded
derive_run = importlib.import_module("softpinn.bridge.cli._derive_run")


def test_derive_derives_once(tmp_path, monkeypatch, capsys):
    calls = []
    real = eom.derive

    def counting(*args, **kwargs):
        calls.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(eom, "derive", counting)
    monkeypatch.setattr(functions_mod, "derive", counting)
    monkeypatch.setattr(derive_run, "derive", counting)
    assert main(["derive", "task1", "--out", str(tmp_path / "d"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert len(calls) == 1
    assert {"derive", "functions"} <= set(summary["timings_s"])


def test_functions_of_equals_functions():
    import numpy as np

    fns = functions_mod.functions_of(eom.derive(functions_mod.load_spec("task4")))
    ref = functions_mod.functions("task4")
    q = np.array([0.3, -0.2, 0.1])
    np.testing.assert_allclose(np.array(fns["M"](q)), np.array(ref["M"](q)), rtol=1e-14)
