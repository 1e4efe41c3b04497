"""iap-mjx: Implicit Attention for Pixels on MJX, trained with evolution strategies on a CPU.

Layers, lowest first (a lower layer never imports a higher one):
``attention`` (feature maps, patches, scores) and ``render`` (ray-cast camera) ->
``envs`` (MJX ports of dm_control tasks) -> ``policies`` -> ``es`` (training) ->
``configs`` (presets) -> ``cli``.
"""

__version__ = "0.1.0"
