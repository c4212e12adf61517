"""Reports of the flat test jobs: the picture frame's frame force and the bias-extension test."""
