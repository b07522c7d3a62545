"""The differential drive in the diagnosis: its adapter, the PyBullet replay of a log, the firmware
conventions, test manoeuvres, the drive-train actuation checks and the env recorder."""
