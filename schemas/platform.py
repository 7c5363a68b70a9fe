"""Platform descriptions (paper section 2): physical data, not code, so a lab adds
its own platform with a file under deploy/platforms/."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from schemas.config import _Model, _name

__all__ = ["PlatformConfig"]


class PlatformConfig(_Model):
    """Physical description of a platform (paper section 2)."""

    name: Annotated[str, _name("platform name")]
    mass: float = Field(gt=0, description="kg")
    inertia: float = Field(gt=0, description="moment of inertia about the vertical axis, kg m^2")
    max_rate: float = Field(
        0.5, gt=0, description="largest heading rate the kinematic model follows, rad/s"
    )
