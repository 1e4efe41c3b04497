"""Environments: MJX ports of dm_control tasks with the brax State convention."""
