"""Rendering with Mitsuba 3 and comparison images."""
