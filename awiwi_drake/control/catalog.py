"""Built-in controller registrations (imported lazily by :mod:`.registry`)."""
