"""Request bodies of the control endpoints, validated by pydantic.

Extra fields are errors, numbers must be real JSON numbers (no strings, no booleans)
and finite. Range limits depend on the app's configuration and are checked by the
handler, which names the field in its 400 answer like pydantic's errors do.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from relayd.core.vocab import Mode

_StrictFloat = Annotated[float, Field(strict=True)]


class ModeRequest(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    mode: Mode


class DriveRequest(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    left_mm_s: _StrictFloat
    right_mm_s: _StrictFloat
