"""The mixture of Markov chains: a frozen dataclass of log-space tensors.

Notation (shared/DESIGN.md): ``K`` clusters (human types), ``A`` symbols (the joint
action alphabet ``A = A_r ∪ A_h`` of the paper), leading batch dims ``...`` first::

    log_transition: (..., K, A, A)  [..., k, a, b] = log P(x_j = b | x_{j-1} = a, z = k)
    log_initial:    (..., K, A)     log_initial[..., k, a] = log P(x_1 = a | z = k), or None
    log_weights:    (..., K)        log_weights[..., k] = log P(z = k)

With ``log_initial = None`` the first symbol is not modelled, as in the paper (Eq. 1:
``P(x_i | z) = prod_{j>=2} theta_z(x_i^j | x_i^{j-1})``). ``-inf`` entries (probability 0,
e.g. transitions never seen by the paper's hard EM) are allowed; ``nan`` and ``+inf`` are not.

Files: ``.json`` (probabilities as nested lists, human readable) or ``.safetensors``
(exact log values plus JSON metadata); never pickle. Writes are atomic.

Example:
    >>> import torch
    >>> from torchhrc.mixture import MarkovChainMixture
    >>> m = MarkovChainMixture.uniform(2, 3)
    >>> m.num_clusters, m.num_symbols, tuple(m.log_transition.shape)
    (2, 3, (2, 3, 3))
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from torchhrc._atomic import atomic_write, atomic_write_text
from torchhrc._checks import broadcast_shapes, check_shape, check_tensor, format_index
from torchhrc.errors import ModelError, ParseError
from torchhrc.mixture.history import MAX_ORDER, context_symbols

__all__ = ["MarkovChainMixture"]

_FORMAT = "torchhrc.MarkovChainMixture"
_VERSION = 1


def _check_log_normalised(name: str, value: torch.Tensor, atol: float) -> None:
    """Check ``value`` has no nan/+inf and ``logsumexp(value, -1) == 0`` within ``atol``."""
    if torch.isnan(value).any() or (value == math.inf).any():
        bad = torch.nonzero(torch.isnan(value) | (value == math.inf))[0]
        raise ModelError(
            f"{name}{format_index(bad)} = {value[tuple(bad)].item()} is not a log-probability "
            "(expected a finite value or -inf)"
        )
    if (value > atol).any():
        bad = torch.nonzero(value > atol)[0]
        raise ModelError(
            f"{name}{format_index(bad)} = {value[tuple(bad)].item():.6g} is a log-probability "
            "above 0"
        )
    total = torch.logsumexp(value, dim=-1)
    tol = max(atol, 1e-4 if value.dtype in (torch.float16, torch.bfloat16, torch.float32) else atol)
    off = ~((total.exp() - 1).abs() <= tol)
    if off.any():
        bad = torch.nonzero(off)[0]
        raise ModelError(
            f"{name}{format_index(bad)} row has total probability "
            f"{total[tuple(bad)].exp().item():.6g}, "
            "expected 1 (logsumexp over the last dim must be 0)"
        )


@dataclass(frozen=True)
class MarkovChainMixture:
    """A mixture of ``K`` first-order Markov chains over ``A`` symbols (log space).

    Args:
        log_transition: ``(..., K, A, A)``, ``log P(next = b | previous = a, cluster k)``
            at ``[..., k, a, b]``; each row's ``logsumexp`` is 0.
        log_weights: ``(..., K)``, log mixture weights ``log P(z = k)``.
        log_initial: ``(..., K, A)`` log first-symbol distribution per cluster, or ``None``
            (the paper's model: the first symbol is not scored).
        vocabulary: optional names of the ``A`` symbols, e.g. ``(("human", "place_A"), ...)``
            as in :class:`torchhrc.data.Demonstrations`.
        atol: tolerance of the normalisation check.
        objects: which form of the demonstrations the chains are over: ``"raw"`` (the
            symbols as recorded) or ``"exchangeable"`` (objects renamed in order of first use
            by :meth:`~torchhrc.data.Demonstrations.relabel_objects`, so ``vocabulary`` names
            ``place_1, place_2, ...``). :meth:`prepare` puts new demonstrations in that form.
        object_separator: the separator between verb and object in action names
            (``relabel_objects``'s ``separator``).
        order: ``1``, chains over the symbols (the paper), or ``2`` or ``3``, chains of
            that order: ``vocabulary`` names context symbols ``(previous step, step)`` or
            ``(the two previous steps, step)`` (:mod:`torchhrc.mixture.history`), and
            :meth:`prepare` renames new demonstrations' steps to them.

    Raises:
        TypeError: a field is not a floating tensor.
        ModelError: shapes disagree, a value is nan/+inf, or a distribution does not sum to 1.

    Example:
        >>> import torch
        >>> T = torch.tensor([[[0.9, 0.1], [0.5, 0.5]]], dtype=torch.float64).log()
        >>> m = MarkovChainMixture(T, log_weights=torch.zeros(1, dtype=torch.float64))
        >>> [round(p, 6) for p in m.transition[0, 0].tolist()]
        [0.9, 0.1]
    """

    log_transition: torch.Tensor
    log_weights: torch.Tensor
    log_initial: torch.Tensor | None = None
    vocabulary: tuple[Any, ...] | None = None
    atol: float = dataclasses.field(default=1e-6, repr=False, compare=False)
    objects: str = "raw"
    object_separator: str = "_"
    order: int = 1

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check shapes and normalisation; raise :class:`ModelError` if invalid."""
        T = check_tensor("log_transition", self.log_transition)
        check_shape("log_transition", T, (None, None, None), "(..., K, A, A)")
        K, A = T.shape[-3], T.shape[-1]
        if T.shape[-2] != A:
            raise ModelError(
                "expected log_transition to have shape (..., K, A, A), "
                f"actual shape = {tuple(T.shape)}"
            )
        if K < 1 or A < 1:
            raise ModelError(f"expected K >= 1 and A >= 1, got K = {K}, A = {A}")
        W = check_tensor("log_weights", self.log_weights)
        check_shape("log_weights", W, (K,), f"(..., K={K})")
        shapes = [T.shape[:-3], W.shape[:-1]]
        if self.log_initial is not None:
            I0 = check_tensor("log_initial", self.log_initial)
            check_shape("log_initial", I0, (K, A), f"(..., K={K}, A={A})")
            shapes.append(I0.shape[:-2])
        try:
            broadcast_shapes(*shapes)
        except RuntimeError:
            raise ModelError(
                "batch dims of log_transition, log_weights (, log_initial) do not broadcast: "
                f"{[tuple(s) for s in shapes]}"
            ) from None
        _check_log_normalised("log_transition", T.detach(), self.atol)
        _check_log_normalised("log_weights", W.detach(), self.atol)
        if self.log_initial is not None:
            _check_log_normalised("log_initial", self.log_initial.detach(), self.atol)
        if self.vocabulary is not None:
            vocab = tuple(tuple(v) if isinstance(v, (list, tuple)) else v for v in self.vocabulary)
            if len(vocab) != A:
                raise ModelError(f"expected a vocabulary of A = {A} symbols, got {len(vocab)}")
            object.__setattr__(self, "vocabulary", vocab)
        if self.objects not in ("raw", "exchangeable"):
            raise ModelError(f"expected objects 'raw' or 'exchangeable', got {self.objects!r}")
        if not isinstance(self.object_separator, str) or not self.object_separator:
            raise ModelError(
                f"expected object_separator to be a non-empty str, got {self.object_separator!r}"
            )
        if isinstance(self.order, bool) or self.order not in range(1, MAX_ORDER + 1):
            raise ModelError(f"expected order an int in [1, {MAX_ORDER}], got {self.order!r}")

    def prepare(self, demonstrations: Any) -> Any:
        """New demonstrations in the form and symbol order the chains are over.

        ``objects="exchangeable"``: :meth:`~torchhrc.data.Demonstrations.relabel_objects`
        first; ``order`` 2 or 3: then every step renamed to its context symbol
        (:func:`~torchhrc.mixture.history.context_symbols`). Then, when the model has a
        vocabulary, the symbols are re-indexed to it
        (:meth:`~torchhrc.data.Demonstrations.with_vocabulary`). Score or classify the result
        (:func:`~torchhrc.mixture.infer_type`, :func:`~torchhrc.mixture.sequence_log_likelihood`).

        Args:
            demonstrations: a :class:`~torchhrc.data.Demonstrations`.

        Returns:
            The demonstrations to score (the same object when nothing changes).

        Raises:
            ModelError: a symbol of the demonstrations is not in the model's vocabulary (with
                ``order`` 2 or 3: a step after steps it never followed in the fitted data).

        Example:
            >>> from torchhrc.data import Demonstrations
            >>> T = torch.zeros(1, 2, 2, dtype=torch.float64) - math.log(2)
            >>> m = MarkovChainMixture(T, torch.zeros(1, dtype=torch.float64),
            ...     vocabulary=(("human", "place_1"), ("human", "place_2")), objects="exchangeable")
            >>> d = Demonstrations.from_lists([[("human", "place_B"), ("human", "place_A")]])
            >>> m.prepare(d).sequences
            tensor([[0, 1]])
        """
        if self.objects == "exchangeable":
            demonstrations = demonstrations.relabel_objects(separator=self.object_separator)
        if self.order > 1:
            demonstrations = context_symbols(demonstrations, self.order).data
        if self.vocabulary is not None:
            demonstrations = demonstrations.with_vocabulary(self.vocabulary)
        return demonstrations

    @classmethod
    def uniform(
        cls,
        num_clusters: int,
        num_symbols: int,
        *,
        initial: bool = False,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> MarkovChainMixture:
        """The mixture whose every distribution is uniform (a neutral starting point).

        Example:
            >>> MarkovChainMixture.uniform(2, 4).transition.sum(-1).tolist()
            [[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0]]
        """
        K, A = int(num_clusters), int(num_symbols)
        T = torch.full((K, A, A), -math.log(A), dtype=dtype, device=device)
        W = torch.full((K,), -math.log(K), dtype=dtype, device=device)
        I0 = torch.full((K, A), -math.log(A), dtype=dtype, device=device) if initial else None
        return cls(log_transition=T, log_weights=W, log_initial=I0)

    @property
    def num_clusters(self) -> int:
        """K, the number of clusters (human types)."""
        return self.log_transition.shape[-3]

    @property
    def num_symbols(self) -> int:
        """A, the number of symbols (joint actions)."""
        return self.log_transition.shape[-1]

    @property
    def batch_shape(self) -> torch.Size:
        """The broadcast batch shape of all tensors."""
        shapes = [self.log_transition.shape[:-3], self.log_weights.shape[:-1]]
        if self.log_initial is not None:
            shapes.append(self.log_initial.shape[:-2])
        return broadcast_shapes(*shapes)

    @property
    def transition(self) -> torch.Tensor:
        """``(..., K, A, A)`` transition probabilities ``exp(log_transition)``."""
        return self.log_transition.exp()

    @property
    def weights(self) -> torch.Tensor:
        """``(..., K)`` mixture weights ``exp(log_weights)``."""
        return self.log_weights.exp()

    def num_parameters(self) -> int:
        """Free parameters of one mixture: ``K A (A-1) + (K-1)`` (+ ``K (A-1)`` with initials).

        The paper's BIC (Select-Best-Model) counts only ``K A (A-1)``.
        """
        K, A = self.num_clusters, self.num_symbols
        n = K * A * (A - 1) + (K - 1)
        if self.log_initial is not None:
            n += K * (A - 1)
        return n

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> MarkovChainMixture:
        """Return a copy with every tensor moved to ``device`` / cast to ``dtype``."""
        changes = {
            f.name: getattr(self, f.name).to(device=device, dtype=dtype)
            for f in dataclasses.fields(self)
            if isinstance(getattr(self, f.name), torch.Tensor)
        }
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ files
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the model to ``path``: ``.json`` (probabilities) or ``.safetensors``.

        The write is atomic (temporary file + ``os.replace``). Batched models are saved
        with their batch dims.

        Raises:
            ValueError: the suffix is neither ``.json`` nor ``.safetensors``.
        """
        path = Path(path)
        suffix = path.suffix.lower()
        meta: dict[str, Any] = {
            "format": _FORMAT,
            "version": _VERSION,
            "vocabulary": self.vocabulary,
        }
        if self.objects != "raw":  # files of raw models stay as before
            meta.update(objects=self.objects, object_separator=self.object_separator)
        if self.order != 1:
            meta.update(order=self.order)
        tensors = {"log_transition": self.log_transition, "log_weights": self.log_weights}
        if self.log_initial is not None:
            tensors["log_initial"] = self.log_initial
        if suffix == ".json":
            doc = dict(meta)
            doc["dtype"] = str(self.log_transition.dtype).removeprefix("torch.")
            for name, t in tensors.items():
                doc[name.removeprefix("log_")] = t.detach().exp().cpu().tolist()
            text = json.dumps(doc, indent=1)
            atomic_write_text(path, text + "\n")
        elif suffix == ".safetensors":
            from safetensors.torch import save_file

            flat = {k: v.detach().cpu().contiguous() for k, v in tensors.items()}
            metadata = {k: json.dumps(v) for k, v in meta.items()}
            atomic_write(path, lambda tmp: save_file(flat, tmp, metadata=metadata))
        else:
            raise ValueError(f"expected path to end in .json or .safetensors, got {str(path)!r}")

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], *, device: torch.device | str | None = None
    ) -> MarkovChainMixture:
        """Read a model written by :meth:`save`.

        Raises:
            ParseError: the file is not a torchhrc mixture or is malformed (names file and reason).
            FileNotFoundError: ``path`` does not exist.
        """
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".json":
            try:
                doc = json.loads(path.read_text())
            except json.JSONDecodeError as err:
                raise ParseError(
                    f"invalid JSON: {err.msg}", path=str(path), line=err.lineno, column=err.colno
                ) from None
            if not isinstance(doc, dict) or doc.get("format") != _FORMAT:
                raise ParseError(f"not a {_FORMAT} file (missing 'format')", path=str(path))
            dtype = getattr(torch, str(doc.get("dtype", "float64")), None)
            if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
                raise ParseError(f"unknown dtype {doc.get('dtype')!r}", path=str(path))
            tensors = {}
            for key in ("transition", "weights", "initial"):
                if key not in doc or doc[key] is None:
                    if key != "initial":
                        raise ParseError(f"missing field {key!r}", path=str(path))
                    continue
                try:
                    t = torch.tensor(doc[key], dtype=torch.float64, device=device)
                except (TypeError, ValueError) as err:
                    raise ParseError(f"field {key!r}: {err}", path=str(path)) from None
                tensors[f"log_{key}"] = t.log().to(dtype)
            vocabulary = doc.get("vocabulary")
            objects = doc.get("objects", "raw"), doc.get("object_separator", "_")
            order = doc.get("order", 1)
        elif suffix == ".safetensors":
            from safetensors import SafetensorError, safe_open

            try:
                with safe_open(str(path), framework="pt", device="cpu") as f:
                    metadata = f.metadata() or {}
                    tensors = {k: f.get_tensor(k) for k in f.keys()}
            except SafetensorError as err:
                raise ParseError(f"invalid safetensors file: {err}", path=str(path)) from None
            if json.loads(metadata.get("format", "null")) != _FORMAT:
                raise ParseError(f"not a {_FORMAT} file (missing 'format')", path=str(path))
            for key in ("log_transition", "log_weights"):
                if key not in tensors:
                    raise ParseError(f"missing tensor {key!r}", path=str(path))
            tensors = {k: v.to(device) for k, v in tensors.items()}
            try:
                vocabulary = json.loads(metadata.get("vocabulary", "null"))
                objects = (
                    json.loads(metadata.get("objects", '"raw"')),
                    json.loads(metadata.get("object_separator", '"_"')),
                )
                order = json.loads(metadata.get("order", "1"))
            except json.JSONDecodeError as err:
                raise ParseError(f"invalid metadata: {err.msg}", path=str(path)) from None
        else:
            raise ValueError(f"expected path to end in .json or .safetensors, got {str(path)!r}")
        try:
            return cls(
                log_transition=tensors["log_transition"],
                log_weights=tensors["log_weights"],
                log_initial=tensors.get("log_initial"),
                vocabulary=tuple(vocabulary) if vocabulary is not None else None,
                objects=objects[0],
                object_separator=objects[1],
                order=order,
            )
        except (ModelError, TypeError) as err:
            raise ParseError(f"invalid model: {err}", path=str(path)) from None
