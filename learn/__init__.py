"""Physics-inspired networks (JAX, Equinox, optax): Lagrangian, Hamiltonian and black-box
dynamics models, one-step Runge-Kutta losses, training and prediction. Never imports casadi."""

from .errors import UserError

__all__ = ["UserError"]
