"""iap-mjx: Implicit Attention for Pixels on MJX, trained with evolution strategies on a CPU.

Layers, lowest first (a lower layer never imports a higher one):
``configs`` (frozen configuration dataclasses and the preset table: plain data) and ``chunks``
(a batch as a loop over chunks: jax only) ->
``attention`` (feature maps, patches, scores) and ``render`` (ray-cast camera) ->
``envs`` (MJX ports of dm_control tasks) -> ``policies`` -> ``es`` (training) -> ``cli``.
(``PolicySpec`` looks up the policy kinds when it is validated: its one upward lookup.)
"""

__version__ = "0.1.0"
