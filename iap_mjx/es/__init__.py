"""Evolution strategies: the compiled population evaluation, the update and train()."""
