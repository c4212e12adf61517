"""What a run writes and keeps: results writer, checkpoints, results folders, progress, writes
that survive a full disk, and clean stops on signals."""
