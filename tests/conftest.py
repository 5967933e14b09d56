"""Shared test settings.

The suite runs with ``pytest -n 2`` on two cores: one torch thread per worker avoids
oversubscription, which makes small tensor work many times slower.
"""

import torch

torch.set_num_threads(1)
