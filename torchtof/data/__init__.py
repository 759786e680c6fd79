"""Procedural data for the learned reconstructor: seeded scenes and bucket noise (no downloads)."""

from .noise import TRAIN_LEVELS, NoiseRecipe, noisy_buckets, training_noise
from .scenes import (
    EVAL_SEED_BASE,
    FAMILIES,
    HELD_OUT_IMAGES,
    IMAGE_SUFFIXES,
    TRAIN_IMAGES,
    check_families,
    draw_scene,
    draw_scenes,
    grey_image,
    image_files,
    load_images,
    planar_depth,
)

__all__ = [
    "FAMILIES",
    "TRAIN_IMAGES",
    "HELD_OUT_IMAGES",
    "EVAL_SEED_BASE",
    "check_families",
    "draw_scene",
    "draw_scenes",
    "grey_image",
    "load_images",
    "image_files",
    "IMAGE_SUFFIXES",
    "planar_depth",
    "NoiseRecipe",
    "noisy_buckets",
    "training_noise",
    "TRAIN_LEVELS",
]
