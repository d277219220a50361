"""The parametric mannequin: shape parameters, its skeleton, skinned mesh and colliders."""
