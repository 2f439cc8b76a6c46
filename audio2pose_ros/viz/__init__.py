"""Pictures of motion: rendering, filter plots and Foxglove bags."""
