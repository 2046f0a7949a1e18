"""What every layer shares and nothing else: the error type, atomic file writes, the cache folder,
the progress callback. Standard library only."""
