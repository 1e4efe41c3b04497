"""Loop carries under ``vmap``: batch every leaf up front so JAX batches the body once.

Under ``vmap``, JAX's batching rule for ``lax.scan``/``fori_loop``/``while_loop`` re-batches
the loop's body until the carry's batched leaves stop changing. A carry that starts partly
unbatched (a zero return, a ``False`` flag, the fields MJX's ``make_data`` fills with
constants) costs a second pass, or more: each pass traces the whole body again, and for an
MJX physics step inside the rollout each trace adds to the program's compile time. Handing the
loop a carry whose leaves are all batched ends it in one pass. Outside ``vmap`` (and after
batching) the marking is ``select(p, x, x)``, which XLA removes.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp


def batched_like(tree: Any, like: jax.Array) -> Any:
    """``tree`` unchanged in value, each leaf made to vary with ``like`` under ``vmap``.

    Args:
      tree: any pytree of arrays (a loop's initial carry).
      like: an array that is batched whenever the loop is (an episode's key, a state leaf
        drawn from it).

    Returns:
      ``tree`` with the same values, shapes and dtypes; under ``vmap`` every leaf is batched
      along ``like``'s batch axis.
    """
    first = jnp.ravel(like)[0]
    marker = first == first  # any batched predicate: select(p, x, x) is x whatever p is
    # lax.select, not jnp.where: jnp.where returns a zero-size operand as it is (unbatched),
    # and MJX's data has zero-size fields.
    return jax.tree.map(lambda x: jax.lax.select(jnp.broadcast_to(marker, jnp.shape(x)), x, x), tree)
