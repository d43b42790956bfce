"""The network fields every algorithm's config shares: the observation's scaling, the hidden
layers and mirror symmetry (each algorithm's own network fields are in its options)."""

from __future__ import annotations

from dataclasses import dataclass

from dockingrl.agents.option_fields import documented, refuse

#: ``mirror_symmetric``: which networks are made mirror-symmetric
MIRROR_SYMMETRIC = ("none", "actor", "all")


@dataclass
class NetworkOptions:
    """The actor's and critics' shape."""

    normalize_observation: bool = documented(
        "scale the range by 1/max_dist inside the networks (not in the paper)", default=False
    )
    hidden: tuple[int, ...] = documented(
        "hidden layer sizes of actor and critic", default=(256, 256)
    )
    mirror_symmetric: str = documented(
        "mirror-symmetric networks (not in the paper): 'actor' makes the actor command the "
        "mirrored command in the mirrored situation (y -> -y), exactly, by averaging it over "
        "the observation and its mirror (dockingrl.agents.mirror.MirrorSymmetric); 'all' "
        "the critics too (they value a transition and its mirror alike). A SAC update costs about "
        "1.3x ('actor') and 1.8x ('all') the plain one on a 2-core CPU; 'none' neither",
        default="none",
    )

    def _check_network(self) -> None:
        """Refuse a network field out of its range, naming it."""
        if not self.hidden or any(h < 1 for h in self.hidden):
            refuse(self, "hidden", "needs positive layer sizes")
        if self.mirror_symmetric not in MIRROR_SYMMETRIC:
            refuse(
                self,
                "mirror_symmetric",
                f"valid: {', '.join(MIRROR_SYMMETRIC)}",
            )
