"""Unattended campaigns: a night of acquire and calibrate jobs (docs/campaigns.md)."""
