"""Loops with a traced trip count under a static cap, so that one compiled program serves every iteration count.

An iteration count is a traced config value (users sweep it); the program is compiled for a static *cap*
(:func:`cap_for`: the next power of two, at least :data:`MIN_CAP`), so every count up to the cap runs the same
program. :func:`counted_scan` runs such a loop in one of two forms, a static choice of the program
(:attr:`LoopCaps.differentiable`):

* a ``lax.while_loop`` that stops at the count (the default: what a SLAM run needs, forward only). It costs the
  iterations run, nothing for the cap;
* a ``lax.scan`` over the cap whose iterations from the count on are skipped by ``lax.cond``, for programs that
  reverse mode must pass through (hypergradients differentiate through the tracker's iterations; a while loop has
  no reverse mode). Each iteration is a ``jax.checkpoint``: the backward pass keeps the carries alone and
  recomputes an iteration's inside (without it a hypergradient of 10 frames at 80x60 asked for 108 GB). It costs
  more per iteration run: on XLA:CPU a SLAM step of the ``cpu`` preset took 21 % longer with every loop in this
  form (frame 16 of the noisy synthetic room, 1256 against 1038 ms, medians of 9 interleaved runs in one process),
  so a run does not use it.

Under ``vmap`` with counts that differ between the batch entries, both forms run every entry until the largest
count (the while loop's predicate and the cond's are then batched): a batched program costs its largest count.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.config.fields import is_checkable

_Carry = TypeVar("_Carry")

MIN_CAP = 32  # every count up to 32 (the cpu preset's, the tests') shares one program


def cap_for(count: int) -> int:
    """The static cap of a loop that runs ``count`` iterations: 0 for 0 (the loop is not compiled), else the
    smallest power of two >= ``count`` and >= :data:`MIN_CAP`.

    Args:
      count: the iteration count (>= 0).

    Returns:
      The cap, an int.
    """
    count = int(count)
    if count <= 0:
        return 0
    return max(MIN_CAP, 1 << (count - 1).bit_length())


def counted_scan(body: Callable[[jax.Array, _Carry], _Carry], init: _Carry, count: int | jax.Array, cap: int,
                 running: Callable[[_Carry], jax.Array] | None = None, differentiable: bool = False) -> _Carry:
    """``min(count, cap)`` iterations of ``carry = body(i, carry)``, i = 0, 1, ...

    With ``running``, the loop also stops before the first iteration where ``running(carry)`` is false (an early
    stop). A ``lax.while_loop``, or with ``differentiable`` a ``lax.scan`` over ``cap`` iterations whose iterations
    from the count (or the stop) on take the identity branch of a ``lax.cond`` (reverse mode passes through it).

    Args:
      body: ``body(i, carry) -> carry``, i a [] int32 (traced).
      init: the carry before the first iteration.
      count: the iterations to run (may be traced); at most ``cap`` run.
      cap: the static bound (0: ``init`` is returned, nothing is compiled).
      running: ``running(carry) -> [] bool``, whether to go on (an early stop); None: until ``count``.
      differentiable: the scan form, for reverse mode (static).

    Returns:
      The carry after the iterations run.
    """
    if cap <= 0:
        return init
    if not differentiable:
        def going(state):
            i, carry = state
            go = i < jnp.minimum(count, cap)
            return go if running is None else go & running(carry)

        return jax.lax.while_loop(going, lambda state: (state[0] + 1, body(*state)), (jnp.int32(0), init))[1]

    # Each iteration is recomputed in the backward pass (only the carries are kept): memory bounded by the cap.
    body = jax.checkpoint(body, prevent_cse=False)

    def step(carry, i):
        go = i < count
        if running is not None:
            go = go & running(carry)
        return jax.lax.cond(go, lambda c: body(i, c), lambda c: c, carry), None

    return jax.lax.scan(step, init, jnp.arange(cap, dtype=jnp.int32))[0]


def loop_caps(config: Any) -> LoopCaps:
    """``config.caps``, the static caps of a :class:`gsjax.slam.config.SlamConfig`'s loops.

    Args:
      config: the SLAM config.

    Returns:
      Its caps.

    Raises:
      ValueError: the config was built with traced iteration counts and no caps.
    """
    if config.caps is None:
        raise ValueError("SlamConfig.caps is unset: build the config with concrete iteration counts (or give it caps, "
                         "SlamConfig.with_caps) before tracing it")
    return config.caps


def common_caps(configs: Iterable[Any]) -> LoopCaps:
    """The caps that hold every one of ``configs``' loops and flags (the union of their caps), for configs that are to
    share one program (:meth:`gsjax.slam.config.SlamConfig.with_caps`).

    Args:
      configs: SLAM configs.

    Returns:
      The caps.
    """
    return functools.reduce(LoopCaps.union, [c.caps for c in configs if c.caps is not None], LoopCaps())


def compiles_noise(config: Any) -> bool:
    """Whether a :class:`gsjax.slam.config.SlamConfig`'s program draws the noise of its ``noise`` levels
    (:attr:`LoopCaps.noise`; True when the config has no caps yet).

    Args:
      config: the SLAM config.

    Returns:
      A static bool.
    """
    return config.caps is None or config.caps.noise


def is_differentiable(config: Any) -> bool:
    """Whether a :class:`gsjax.slam.config.SlamConfig`'s program is differentiated through its loops
    (:attr:`LoopCaps.differentiable`; False when the config has no caps yet).

    Args:
      config: the SLAM config.

    Returns:
      A static bool.
    """
    return config.caps is not None and config.caps.differentiable


def compiles_smoothing(config: Any) -> bool:
    """Whether a :class:`gsjax.slam.config.SlamConfig`'s program carries CB-KNN's per-pixel correction in its renders
    (:attr:`LoopCaps.smoothing`; True when the config has no caps yet).

    Args:
      config: the SLAM config.

    Returns:
      A static bool.
    """
    return config.caps is None or config.caps.smoothing


@dataclasses.dataclass(frozen=True)
class LoopCaps:
    """The static part of a SLAM program's loops: each loop's cap (:func:`cap_for`; 0: not compiled), whether
    mapping carries a contributor selection per window view (``mapping.reselect_every`` > 1: a [V, K, P] buffer), and
    whether CB-KNN's per-pixel correction is compiled into the renders (``cbknn.mode`` ``paper``).

    Derived from a config's traced counts (:meth:`of`) and held in its tree structure (``SlamConfig.caps``), so two
    configs whose counts share the caps share one compiled program.

    Attributes:
      tracking: cap of the tracker's iterations on every pixel (``tracking.iters``).
      tracking_strided: cap of its strided iterations (``tracking.strided_iters``).
      tracking_coarse: cap of its coarse-to-fine iterations (``tracking.coarse.iters``, all levels).
      mapping: cap of the mapping iterations on every pixel (``mapping.iters``).
      mapping_strided: cap of the strided mapping iterations (``mapping.strided_iters``).
      mapping_reselect: mapping chooses the window views' contributors every ``mapping.reselect_every`` iterations
        and carries them in between.
      smoothing: the renders carry CB-KNN's correction as a branch on the traced keyframe-and-mode flag (``paper``
        mode, or a sweep with it among its modes). Without it (``off``, ``code_parity``) the renders are canonical
        with no branch: on XLA:CPU the branch's outputs, K x P slot arrays per render, cost copies and fusions
        (a ``cpu`` step about 4 % slower, a whole run's SLAM 8-11 %, with the branch compiled and never taken).
      noise: the step draws the noise of ``config.noise`` (some level above 0, or traced levels). Without it no draw
        is compiled: XLA:CPU compiles both branches of the ``lax.cond`` that skips zero noise, and the draws were 8 %
        of the fusions of a SLAM program that never took them (its compile 10-18 % longer).
      differentiable: the loops take the form reverse mode passes through (:func:`counted_scan`: a scan over the
        cap, slower per iteration), for programs that differentiate through them; False (a run): while loops.
      pinned: given on purpose (:meth:`gsjax.slam.config.SlamConfig.with_caps`: kept, and raised only where a count
        outgrows them); otherwise derived from the counts, and derived anew whenever the counts change.
    """

    tracking: int = 0
    tracking_strided: int = 0
    tracking_coarse: int = 0
    mapping: int = 0
    mapping_strided: int = 0
    mapping_reselect: bool = False
    smoothing: bool = False
    noise: bool = False
    differentiable: bool = False
    pinned: bool = dataclasses.field(default=False, compare=False, repr=False)  # not part of the program

    @staticmethod
    def of(config: Any, exact: bool = False) -> LoopCaps | None:
        """The caps a :class:`gsjax.slam.config.SlamConfig`'s counts need (the largest over a stacked batch of
        configs); None when a count is traced (not concrete).

        Args:
          config: the SLAM config.
          exact: each cap the count itself, not :func:`cap_for`'s (a batched program runs its whole cap).

        Returns:
          The caps, or None.
        """
        counts = (config.tracking.iters, config.tracking.strided_iters, config.tracking.coarse.iters,
                  config.mapping.iters, config.mapping.strided_iters, config.mapping.reselect_every)
        mode = config.cbknn.mode
        if not all(is_checkable(c) for c in counts) or not (isinstance(mode, str) or is_checkable(mode)):
            return None
        paper = config.cbknn.smooth_renders
        levels = config.noise.levels()
        noise = not is_checkable(levels) or any(bool(np.any(np.asarray(v) > 0)) for v in levels)
        top = [int(np.max(np.asarray(c))) for c in counts]
        bound = (lambda c: c) if exact else cap_for
        return LoopCaps(tracking=bound(top[0]), tracking_strided=bound(top[1]), tracking_coarse=bound(top[2]),
                        mapping=bound(top[3]), mapping_strided=bound(top[4]), mapping_reselect=top[5] > 1,
                        smoothing=bool(np.any(paper)), noise=noise)

    def union(self, other: LoopCaps) -> LoopCaps:
        """Caps that hold both ``self``'s loops and ``other``'s (the larger cap of each loop).

        Args:
          other: the other caps.

        Returns:
          The caps, field by field the larger (or either flag).
        """
        bounds = {f.name: max(getattr(self, f.name), getattr(other, f.name)) for f in dataclasses.fields(self)}
        return LoopCaps(**{**bounds, "pinned": self.pinned or other.pinned})

    def loops(self) -> LoopCaps:
        """The caps without :attr:`differentiable` (the bounds alone)."""
        return dataclasses.replace(self, differentiable=False)

    def covers(self, other: LoopCaps) -> bool:
        """Whether every loop of ``other`` fits in ``self``.

        Args:
          other: the caps needed.

        Returns:
          True when each of ``self``'s caps is at least ``other``'s (and each flag of ``other`` is set in ``self``).
        """
        return self.union(other).loops() == self.loops()
