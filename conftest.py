"""Collection settings for the doctests of the package (``testpaths`` includes ``torchhrc``).

``torchhrc.envs`` needs the optional ``gym`` extra: without gymnasium its doctests are not
collected (its tests in ``tests/envs`` skip with the reason).
"""

import importlib.util

collect_ignore = []
if importlib.util.find_spec("gymnasium") is None:
    collect_ignore.append("torchhrc/envs")
