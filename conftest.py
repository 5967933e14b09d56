"""Collection settings for the doctests of the package (``testpaths`` includes ``torchhrc``).

``torchhrc.envs`` needs the optional ``gym`` extra: without gymnasium its doctests are not
collected (its tests in ``tests/envs`` skip with the reason).
"""

collect_ignore = []
try:
    import gymnasium  # noqa: F401
except ImportError:
    collect_ignore.append("torchhrc/envs")
