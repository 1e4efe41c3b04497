"""The ray-cast RGB-D camera: MJX state -> pixels."""
