"""The part of a checkpoint each pipeline collaborator owns (Pipeline.state composes them)."""
from __future__ import annotations

from typing import Any, ClassVar

__all__ = ['Checkpointed']


class Checkpointed:
    """A collaborator whose attributes named in STATE a resumed run needs; the others it rebuilds
    from the configuration or is handed by the Pipeline (references to the other collaborators).

    STATE: (checkpoint key, attribute) pairs. The keys are those of the flat checkpoint dict written
    since STATE_VERSION 4 (before the split), so checkpoints of either layout load alike.
    """

    STATE: ClassVar[tuple[tuple[str, str], ...]] = ()
    #: keys a state of the same version may lack (written before they existed): the fresh value stays
    NEWER: ClassVar[frozenset[str]] = frozenset()

    def state(self) -> dict[str, Any]:
        """{checkpoint key: the attribute's value} for each of STATE."""
        return {key: getattr(self, attr) for key, attr in self.STATE}

    def restore(self, state: dict[str, Any]) -> None:
        """Set the attributes of STATE from a checkpoint dict (keys it lacks keep their fresh value)."""
        for key, attr in self.STATE:
            if key in state:
                setattr(self, attr, state[key])
