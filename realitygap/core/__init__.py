"""The floor every layer stands on: geometry, file output and execution helpers.

Pure numpy / standard library; nothing here imports another ``realitygap`` layer.
"""
