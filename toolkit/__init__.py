"""The face of glacimap: pipeline, command line, export and report.

Only ``toolkit`` sees every other package (DESIGN.md §2).
"""
