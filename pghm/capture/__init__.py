"""``pghm capture``: a video of a person becomes a subject folder (docs/capture.md).

    capture(input, out, config)    the whole pipeline (pghm.capture.pipeline)
    CaptureConfig                  its options
    Observations                   what the front end measures per frame
    BodyFit, BodyFitConfig         the body fit's result and settings (pghm.capture.bodyfit)

The body fit loads torch and the body model, so it is imported on first use only.
"""

from pghm.capture.config import CaptureConfig
from pghm.capture.frontend import Observations
from pghm.capture.pipeline import capture

_BODY_FIT_NAMES = ("BodyFit", "BodyFitConfig", "fit_body")


def __getattr__(name: str):
    if name in _BODY_FIT_NAMES:
        from pghm.capture import bodyfit

        return getattr(bodyfit, name)
    raise AttributeError(f"module 'pghm.capture' has no attribute {name!r}")


__all__ = ["CaptureConfig", "Observations", "capture", *_BODY_FIT_NAMES]
