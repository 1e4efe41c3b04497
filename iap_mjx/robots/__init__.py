"""Robot descriptions shared by envs and policies (numbers and MJCF, no simulation):
``a1`` is the A1-class quadruped of ``quadruped-flat`` and ``quadruped-walls``."""
