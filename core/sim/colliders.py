"""Old import path of the body collider, kept only until every caller imports
:mod:`core.body.colliders` (the one implementation). Nothing is defined here."""

from core.body.colliders import (  # noqa: F401
    BodyCapsules,
    body_capsules,
    is_arm,
    pose_capsules,
    select_capsules,
)
