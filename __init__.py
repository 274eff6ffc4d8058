"""ComfyUI's entry to matup's nodes when this repository is cloned into ComfyUI/custom_nodes/
(as ComfyUI-Manager and the registry install a pack); the nodes are in comfyui/.

ComfyUI names a pack's module after its folder's full path, so the pack's folder name never
shadows the ``matup`` package the nodes import. Older ComfyUI named it after the folder
alone: there a clone into ``custom_nodes/matup`` would be ``matup`` itself, and this says so.
"""

if __name__ == "matup":
    raise ImportError(
        "matup's ComfyUI nodes were loaded as the module 'matup', the name of the Python package "
        "they use: clone the repository as custom_nodes/matup-nodes (or update ComfyUI)"
    )

from .comfyui import NODE_CLASS_MAPPINGS, NODE_DISPLAY_NAME_MAPPINGS

__all__ = ["NODE_CLASS_MAPPINGS", "NODE_DISPLAY_NAME_MAPPINGS"]
