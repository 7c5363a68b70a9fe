"""Scenarios an agent flies, one module each, found by name (:data:`schemas.scenario.SCENARIOS`).

- :mod:`agents.scenarios.attitude`: ``attitude-tracking``, the paper's experiment: the
  runtime's own heading guidance;
- :mod:`agents.scenarios.formation`: ``formation``, N platforms keep slots around a
  circling centre;
- :mod:`agents.scenarios.docking`: ``docking``, a chaser docks with a target from
  emulated relative measurements.

A new scenario is one module: a :class:`Scenario` subclass with its name, its config
model (``settings``) and its :meth:`Scenario.reference`, registered by name
(:func:`agents.registry.register_scenario`, or a ``fedlab.scenarios`` entry point).
"""

from __future__ import annotations

from agents.scenarios.base import Others, Scenario

__all__ = ["Others", "Scenario"]
