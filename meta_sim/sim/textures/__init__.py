"""Roof texture banks: the procedural default bank, the held-out sets, users'
photo folders, the HSV colour similarity between textures, and contact
sheets. Pure Python + numpy (OpenImageIO only to read photos); never imports
bpy or torch."""

from .bank import (
    BANK_FORMAT,
    BANK_VERSION,
    KINDS,
    MANIFEST,
    SIMILARITY_FILE,
    SIMILARITY_TO_DEFAULT_FILE,
    TextureBank,
    TextureEntry,
    build_bank_from_folder,
    build_default_bank,
    default_bank_dir,
    ensure_default_bank,
    ensure_heldout_bank,
    ensure_heldout_banks,
    heldout_bank_dir,
    load_bank,
    pixel_sha256,
    save_manifest,
)
from .pngio import write_png
from .procedural import HELDOUT_SETS, Recipe, generate, recipe_by_id, recipes
from .sheet import contact_sheet
from .similarity import (
    Similarity,
    bank_similarity,
    hsv_cone_bins,
    hsv_cone_histogram,
    load_similarity,
    rank_by_similarity,
    similarity,
    similarity_matrix,
    write_similarity,
)

__all__ = [
    "HELDOUT_SETS",
    "BANK_FORMAT",
    "BANK_VERSION",
    "KINDS",
    "MANIFEST",
    "SIMILARITY_FILE",
    "SIMILARITY_TO_DEFAULT_FILE",
    "Recipe",
    "Similarity",
    "TextureBank",
    "TextureEntry",
    "bank_similarity",
    "build_bank_from_folder",
    "build_default_bank",
    "contact_sheet",
    "default_bank_dir",
    "ensure_default_bank",
    "ensure_heldout_bank",
    "ensure_heldout_banks",
    "generate",
    "heldout_bank_dir",
    "hsv_cone_bins",
    "hsv_cone_histogram",
    "load_bank",
    "load_similarity",
    "pixel_sha256",
    "rank_by_similarity",
    "recipe_by_id",
    "recipes",
    "save_manifest",
    "similarity",
    "similarity_matrix",
    "write_png",
    "write_similarity",
]
