"""The building segmenter (the paper's task model): a U-Net, its training on real and rendered images, its scores."""
