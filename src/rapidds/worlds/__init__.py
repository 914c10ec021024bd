"""Simulated worlds: geometry, demonstrations, teammates."""
