"""The wall-climbing robot in the diagnosis: its adapter (tether and ride-height features)."""
