"""Pictures of results: figures, reward curves, videos."""
