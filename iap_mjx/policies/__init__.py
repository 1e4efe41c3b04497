"""Policies: observation -> action (IAP + controller, brute-force attention, CNN)."""
