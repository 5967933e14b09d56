"""File formats: Cassandra ``.pomdp``, APPL ``.pomdpx`` (read and write), ``.policyx``, safetensors.

Example:
    >>> from torchhrc.io import format_pomdp, read_pomdp
    >>> from torchhrc.tasks.classic import tiger
    >>> read_pomdp(format_pomdp(tiger())).num_actions
    3
"""

from __future__ import annotations

from torchhrc.io.cassandra import format_pomdp, parse_pomdp, read_pomdp, write_pomdp
from torchhrc.io.policyx import (
    format_policyx,
    load_policy,
    read_policy_safetensors,
    read_policyx,
    save_policy,
    write_policy_safetensors,
    write_policyx,
)
from torchhrc.io.pomdpx import (
    PomdpxVariable,
    PomdpxVariables,
    format_pomdpx,
    parse_pomdpx,
    read_pomdpx,
    read_pomdpx_variables,
    write_pomdpx,
)

__all__ = [
    "PomdpxVariable",
    "PomdpxVariables",
    "format_policyx",
    "format_pomdp",
    "format_pomdpx",
    "load_policy",
    "parse_pomdp",
    "parse_pomdpx",
    "read_policy_safetensors",
    "read_policyx",
    "read_pomdp",
    "read_pomdpx",
    "read_pomdpx_variables",
    "save_policy",
    "write_policy_safetensors",
    "write_policyx",
    "write_pomdp",
    "write_pomdpx",
]
