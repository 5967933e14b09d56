"""File formats: Cassandra ``.pomdp``, APPL ``.pomdpx`` (read and write), ``.policyx``,
safetensors, and demonstrations in shards (CSV, JSON, Parquet).

Example:
    >>> from torchhrc.io import format_pomdp, read_pomdp
    >>> from torchhrc.tasks.classic import tiger
    >>> read_pomdp(format_pomdp(tiger())).num_actions
    3
"""

from __future__ import annotations

from torchhrc.io.cassandra import format_pomdp, parse_pomdp, read_pomdp, write_pomdp
from torchhrc.io.parquet import read_parquet, write_parquet
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
from torchhrc.io.shards import SHARD_SUFFIXES, list_shards, read_shard

__all__ = [
    "SHARD_SUFFIXES",
    "PomdpxVariable",
    "PomdpxVariables",
    "format_policyx",
    "format_pomdp",
    "format_pomdpx",
    "list_shards",
    "load_policy",
    "parse_pomdp",
    "parse_pomdpx",
    "read_parquet",
    "read_policy_safetensors",
    "read_policyx",
    "read_pomdp",
    "read_pomdpx",
    "read_pomdpx_variables",
    "read_shard",
    "save_policy",
    "write_parquet",
    "write_policy_safetensors",
    "write_policyx",
    "write_pomdp",
    "write_pomdpx",
]
