"""The torch pipeline from tiles to designs: features, the roof finders (colour likelihood and
segmenter), training sets and their cached features, cached models, profiles and ``infer``.
Needs no Blender."""
