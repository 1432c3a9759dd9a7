"""The velocity study's settings (:mod:`bridge.challenges.velocity`): what it trains, on which
data, with which budgets, and what its report compares (:mod:`.velocity_report`)."""

from __future__ import annotations

from typing import Any

#: Issue 18's target for task 5: matrices within this many percent of the truth, directly.
TARGET_PERCENT = 5.0
#: The data variants each task's study trains on (task 5: the paper's three rates).
VARIANTS = {"task4": ("main",), "task5": ("50Hz", "100Hz", "1000Hz")}
#: The quick form (CI, under a minute on one core): task 5's 100 Hz data only.
QUICK_VARIANTS = {"task5": ("100Hz",)}
#: The full form's budgets: changes to the task's [data] table, training pairs per model,
#: AdamW epochs and L-BFGS iterations (the same for both networks).
BUDGETS: dict[str, dict[str, Any]] = {
    "task4": {"data": {"train_trajectories": 6, "test_trajectories": 2},
              "samples": 4000, "epochs": 100, "lbfgs": 0},
    "task5": {"data": {"duration": 12.0, "train_trajectories": 6, "test_trajectories": 2},
              "samples": 8000, "epochs": 40, "lbfgs": 0},
}
QUICK = {"task5": {"epochs": 10, "duration": 1.0}}
#: The networks compared: (name, model kind, label); "hamiltonian-rk4" trains with the one-step
#: loss of eq. 8 through the mapped RK4 step where the recipe's loss is eq. 10 (task 5; on
#: the variants of :data:`RK4_VARIANTS`).
MODELS = (("lagrangian", "lagrangian", "Lagrangian (eq. 6)"),
          ("hamiltonian", "hamiltonian", "Hamiltonian from q̇ (eq. 7, p = M̂ q̇)"),
          ("hamiltonian-rk4", "hamiltonian", "Hamiltonian from q̇, eq. 8 (mapped RK4 step)"),
          ("hamiltonian-known", "hamiltonian", "Hamiltonian from q̇, A known"),
          ("lagrangian-force", "lagrangian", "Lagrangian, A known, eq. 10 in force space"),
          ("hamiltonian-force", "hamiltonian",
           "Hamiltonian from q̇, A known, eq. 10 in force space"),
          ("hamiltonian-weighted", "hamiltonian",
           "the same, a second pass weighted by its inertial forces"))
#: The force-space pair (``softpinn train --accel-space force``): eq. 10 as ‖M̂ (q̈ - q̂̈)‖², linear
#: in the networks' M, D, G, with the true A(q) fixed (known actuator model, which pins the scale
#: velocity data leave open) and a constant D (the arms' damping is constant); nothing of the
#: file's momenta is used (no ``mass_init``). Their own budget, the same for both: AdamW
#: epochs, learning rate and batch size (None: the plan's); the quick form takes the quick
#: budget. Every variant of :data:`VARIANTS` trains the pair.
FORCE_MODELS = ("lagrangian-force", "hamiltonian-force", "hamiltonian-weighted")
#: The weighted second pass (``softpinn train --init RUN --accel-weights-from RUN``): from the
#: force-space Hamiltonian network, each coordinate of the force residual weighted by
#: mean(s) / s_i, s_i the rms of that network's M̂ q̈ (:func:`learn._losses.force_weights`), so
#: the light segment's small forces count as much as the heavy one's; its own epochs and lr.
WEIGHTED_BUDGET = {"epochs": 750, "lr": 3e-3}
WEIGHTED_QUICK = {"epochs": 10, "lr": 3e-3}
FORCE_BUDGETS: dict[str, dict[str, Any]] = {
    "task4": {"epochs": 1500, "lr": 1e-2, "batch_size": 64},
    "task5": {"epochs": 1500, "lr": 1e-2, "batch_size": 64},
}
FORCE_QUICK = {"epochs": 30, "lr": 1e-2, "batch_size": None}
RK4_VARIANTS = {"task5": ("100Hz",)}
#: Rollouts integrate with RK4 steps of at most this many seconds (the data's step cut into
#: enough sub-steps, never fewer than the recipe's): a network may learn a mode stiffer than
#: task 5's fastest (3.5 ms), and RK4 at the 50 Hz recipe's 6.7 ms ran the force-space
#: Hamiltonian network away on one test trajectory where 5 ms and 2 ms give it 4.0e-5 alike.
PREDICT_MAX_STEP = 0.005
#: Where the Hamiltonian network from q̇ also trains with the true A(q) fixed (challenge 2a's
#: known actuator model, ``input_form="known"``), which pins the scale velocities leave open.
KNOWN_VARIANTS = {"task4": ("main",), "task5": ("100Hz",)}
#: The excited data set: one variant's data again with every input's frequency drawn up to
#: EXCITED_FREQUENCY [Hz] instead of the [data] table's (task 5: 3 Hz), on which the force-space
#: models of :data:`FORCE_MODELS` train alone. Task 5's light second segment is overdamped (d/m
#: about 185 1/s): inputs to 3 Hz move it quasi-statically, its inertial forces 8-9 % of its
#: damping forces, and its mass (the two smallest eigenvalues of M, nearly all of ‖M⁻¹‖) is
#: weakly determined by any loss; inputs to 15 Hz raise that to about 25 %
#: (:func:`bridge.analysis.excitation.inertial_share`). Sampled at 1000 Hz, so that central
#: differences keep 15 Hz (at 100 Hz their q̈ would lose 15 %). The quick form excites its one
#: variant.
EXCITED_VARIANT = {"task5": "1000Hz"}
EXCITED_QUICK = {"task5": "100Hz"}
EXCITED_FREQUENCY = 15.0
#: The matrices compared, in the table's order (M⁻¹G and M⁻¹A u: the acceleration frame).
COLUMNS = ("M", "M_inv", "D", "G", "A", "Minv_G", "Minv_Au")
LABELS = {"M": "M", "M_inv": "M⁻¹", "D": "D", "G": "G", "A": "A", "Minv_G": "M⁻¹G",
          "Minv_Au": "M⁻¹A u"}
