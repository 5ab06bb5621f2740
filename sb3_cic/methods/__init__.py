"""The unsupervised RL methods: each is the URLB DDPG base plus a skill prior, a reward module and a
fine-tune choice.

Each public name is written once, in :data:`_MODULES`, and imported from its module on first use
(``import sb3_cic.methods`` alone loads no torch); ``sb3_cic`` exports the same names but :data:`PARTS`.
"""

from __future__ import annotations

import importlib
from typing import Any

#: each public name and its module (``sb3_cic.methods.<module>``), in the order of the methods' documentation
_MODULES: dict[str, str] = {
    "CIC": "cic",
    "ICM": "icm",
    "Disagreement": "disagreement",
    "RND": "rnd",
    "APT": "apt",
    "ProtoRL": "proto",
    "DIAYN": "diayn",
    "SMM": "smm",
    "APS": "aps",
    "MOSS": "moss",
    "Fixed": "fixed",
    "APSPolicy": "aps",
    "APSCritic": "aps",
    "APSRegressionCallback": "aps",
}
#: the parts of a method that only this package exports (a method's policy and critic); ``sb3_cic`` the others
PARTS: tuple[str, ...] = ("APSPolicy", "APSCritic")


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        value = getattr(importlib.import_module(f"{__name__}.{_MODULES[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_MODULES})


__all__ = list(_MODULES)
