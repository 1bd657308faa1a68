"""The one typed error the bridge raises for problems the user can fix in the scene: ``AdjustError``, defined in
fullbody_adjust/errors.py (the bone mapping raises it too) and named here for the bridge's modules."""

from ..errors import AdjustError

__all__ = ["AdjustError"]
