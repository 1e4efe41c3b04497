"""Attention over image patches: kernel feature maps (``features``) and IAP (``iap``)."""

from iap_mjx.attention.features import (
    KINDS,
    ROLES,
    Projections,
    closed_form_mse,
    draw_projections,
    feature_count,
    feature_map,
)
from iap_mjx.attention.iap import (
    KERNELS,
    AttentionConfig,
    AttentionParams,
    IAPAttention,
    Selection,
    brute_scores,
    extract_patches,
    hybrid_scores,
    linear_scores,
    patch_centres,
    top_l,
)

__all__ = [
    "KINDS", "ROLES", "KERNELS", "Projections", "closed_form_mse", "draw_projections",
    "feature_count", "feature_map", "AttentionConfig", "AttentionParams", "IAPAttention",
    "Selection", "brute_scores", "extract_patches", "hybrid_scores", "linear_scores",
    "patch_centres", "top_l",
]
