"""Exchange formats: RGL .bsdf (RGB, as Mitsuba 3's ``measured`` plugin reads it) and MERL .binary."""
