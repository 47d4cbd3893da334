"""Exchange formats: RGL .bsdf (Mitsuba 3, pbrt-v4) and MERL .binary."""
