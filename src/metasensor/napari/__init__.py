"""metasensor's napari plugin (npe2): readers for frames, view stacks, calibrations and result
folders; widgets that run the pipeline's commands; and explorers of the light field.

Install with ``pip install 'metasensor[napari]'``; napari finds the plugin through the
``napari.manifest`` entry point (``napari.yaml`` in this package). Nothing here is imported by
``import metasensor``.
"""
