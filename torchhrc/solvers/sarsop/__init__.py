"""SARSOP (Kurniawati, Hsu & Lee 2008) with the MOMDP factoring (Ong et al. 2010).

The search and its parts: see :mod:`torchhrc.solvers.sarsop.search`.
"""

from __future__ import annotations

from torchhrc.solvers.sarsop.search import LowerInit as LowerInit
from torchhrc.solvers.sarsop.search import SARSOPConfig, fib_corner_values, sarsop
from torchhrc.solvers.sarsop.search import UpperInit as UpperInit

__all__ = ["SARSOPConfig", "fib_corner_values", "sarsop"]
