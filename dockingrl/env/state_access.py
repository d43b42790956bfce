"""The whole state of :class:`~dockingrl.env.DockingEnv`'s simulator, read, written and
stepped from outside its episodes: what a planner rolls forward (:mod:`dockingrl.planning`)."""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase


class StateAccessMixin:
    """:meth:`get_state`, :meth:`set_state` and :meth:`simulate` of
    :class:`~dockingrl.env.DockingEnv` (which holds the state in the attributes
    :attr:`_STATE_ATTRIBUTES` and gives ``_transition``, ``_validated_action`` and, from its
    realism part, ``_realism_attributes`` and ``_after_realism_state_set``)."""

    #: the simulator's whole state, as :meth:`get_state` returns it (``step_count`` is int64),
    #: and the attribute holding each entry
    STATE_KEYS = ("pose", "velocity", "ocean_current", "integral", "previous_error", "step_count")
    _STATE_ATTRIBUTES = (
        "_pose",
        "_velocity",
        "_current",
        "_integral",
        "_previous_error",
        "_step_count",
    )

    def get_state(self) -> TensorDict:
        """The simulator's whole state, a copy: ``pose`` ``(n, 3)``, ``velocity`` ``(n, 3)``,
        ``ocean_current`` ``(n, 2)``, the PID's ``integral`` and ``previous_error`` ``(n, 2)``
        and ``step_count`` ``(n, 1)``; with realism options on, also ``realism``: their per-env
        state (the episode's vehicle factors, the current's mean, bias and believed value, the
        held readings, the sensors' ages, the USBL's delay line and its dropout state). With
        :meth:`set_state` and :meth:`simulate` it lets a planner roll the dynamics forward
        from any state (:mod:`dockingrl.planning`)."""
        pairs = zip(self.STATE_KEYS, self._STATE_ATTRIBUTES, strict=True)
        state = {key: getattr(self, name).clone() for key, name in pairs}
        realism = self._realism_attributes()
        if realism:
            state["realism"] = {name.lstrip("_"): getattr(self, name).clone() for name in realism}
        return TensorDict(state, batch_size=self.batch_size, device=self.device)

    def set_state(self, state: TensorDictBase) -> None:
        """Continue from ``state`` (as :meth:`get_state` returns it, same batch size and
        shapes). This is the bare simulator's state: the transforms above it (the EKF's
        estimate, the previous command, a held action, reward sums) keep their own."""
        missing = [k for k in self.STATE_KEYS if k not in state.keys()]
        if missing:
            raise KeyError(f"state lacks {missing}; expected {list(self.STATE_KEYS)}")
        if tuple(state.batch_size) != tuple(self.batch_size):
            raise ValueError(
                f"state batch size {tuple(state.batch_size)} != env's {tuple(self.batch_size)}"
            )
        values = {}
        for key, name in zip(self.STATE_KEYS, self._STATE_ATTRIBUTES, strict=True):
            value, expected = state[key], getattr(self, name)
            if value.shape != expected.shape:
                raise ValueError(
                    f"state[{key!r}] must have shape {tuple(expected.shape)}, "
                    f"got {tuple(value.shape)}"
                )
            if key == "step_count":
                if value.is_floating_point() or value.is_complex() or bool((value < 0).any()):
                    raise ValueError("state['step_count'] must hold integers >= 0")
            elif not bool(torch.isfinite(value).all()):
                raise ValueError(f"state[{key!r}] must be finite")
            values[name] = value.to(device=self.device, dtype=expected.dtype).clone()
        values.update(self._checked_realism_state(state))
        for name, value in values.items():
            setattr(self, name, value)
        self._after_realism_state_set()

    def _checked_realism_state(self, state: TensorDictBase) -> dict[str, torch.Tensor]:
        """The realism options' state in ``state["realism"]``, checked against the env's."""
        names = self._realism_attributes()
        if not names:
            if "realism" in state.keys():
                raise ValueError("state has a 'realism' entry, but this env has no realism on")
            return {}
        if "realism" not in state.keys():
            raise KeyError(
                "state lacks 'realism': this env's realism options are on (get_state gives it)"
            )
        realism, values = state["realism"], {}
        for name in names:
            key, expected = name.lstrip("_"), getattr(self, name)
            if key not in realism.keys():
                raise KeyError(f"state['realism'] lacks {key!r}")
            value = realism[key]
            if value.shape != expected.shape:
                raise ValueError(
                    f"state['realism'][{key!r}] must have shape {tuple(expected.shape)}, "
                    f"got {tuple(value.shape)}"
                )
            if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                raise ValueError(f"state['realism'][{key!r}] must be finite")
            if not value.is_floating_point() and value.dtype != torch.bool:
                if bool((value < 0).any()):
                    raise ValueError(f"state['realism'][{key!r}] must hold integers >= 0")
            values[name] = value.to(device=self.device, dtype=expected.dtype).clone()
        return values

    def simulate(
        self, state: TensorDictBase, action: torch.Tensor
    ) -> tuple[TensorDict, dict[str, torch.Tensor]]:
        """One noise-free step of the dynamics from ``state`` (any batch size), without
        touching the env's own state: ``(next_state, out)`` with ``out`` the step's entries
        (``reward``, ``terminated``, ``success``, ``contact_score``, ``contact_speed``, ...).
        ``action`` ``(batch, 2)`` is clipped to the bounds of eq. 3, as :meth:`step` does.

        It steps the paper's vehicle, or the nominal Fossen vehicle (``vehicle="fossen"``
        without dynamics mismatch; ``state["realism"]["thrust"]`` carries its thrusters). The
        current is held as ``state`` gives it, and the other realism state (the sensors') is
        carried unchanged: the step of the dynamics, not of the sensors."""
        cfg = self.config
        if cfg.vehicle == "mixed" or (cfg.vehicle == "fossen" and cfg.dynamics_mismatch):
            raise ValueError(
                "simulate steps the paper's vehicle or the nominal Fossen vehicle, not "
                f"vehicle={cfg.vehicle!r} with dynamics_mismatch={cfg.dynamics_mismatch}"
            )
        action = self._validated_action(action, state.batch_size)
        if cfg.vehicle == "paper":
            pose, velocity, integral, error, step_count, out = self._transition(
                state["pose"],
                state["velocity"],
                state["ocean_current"],
                state["integral"],
                state["previous_error"],
                state["step_count"],
                action,
                None,
            )
        else:
            pose, velocity, integral, error, step_count, out, thrust = self._simulate_fossen(
                state, action
            )
        values = (pose, velocity, state["ocean_current"], integral, error, step_count)
        next_state = TensorDict(
            dict(zip(self.STATE_KEYS, values, strict=True)),
            batch_size=state.batch_size,
            device=self.device,
        )
        if "realism" in state.keys():
            realism = state["realism"].clone()
            if cfg.vehicle != "paper":
                realism["thrust"] = thrust
            next_state["realism"] = realism
        return next_state, out
