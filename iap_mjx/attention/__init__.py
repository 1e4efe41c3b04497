"""Attention over image patches: kernel feature maps (``features``), patches (``patches``),
patch scores (``scores``), top-l selection (``selection``) and the IAP layer (``layer``)."""

from iap_mjx.attention.features import (
    KINDS,
    ROLES,
    Projections,
    closed_form_mse,
    draw_projections,
    feature_count,
    feature_map,
)
from iap_mjx.attention.layer import KERNELS, AttentionConfig, AttentionParams, IAPAttention, Selection
from iap_mjx.attention.patches import extract_patches, patch_centres
from iap_mjx.attention.scores import brute_scores, hybrid_scores, linear_scores
from iap_mjx.attention.selection import top_l

__all__ = [
    "KINDS",
    "ROLES",
    "KERNELS",
    "Projections",
    "closed_form_mse",
    "draw_projections",
    "feature_count",
    "feature_map",
    "AttentionConfig",
    "AttentionParams",
    "IAPAttention",
    "Selection",
    "brute_scores",
    "extract_patches",
    "hybrid_scores",
    "linear_scores",
    "patch_centres",
    "top_l",
]
