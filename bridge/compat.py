"""Differences between supported Blender versions that are not about data (see actions.py for those)."""
import bpy

#: Built-in shader for round points: Blender 4.5+ has a dedicated one and deprecates drawing
#: points with UNIFORM_COLOR; 4.2 only has UNIFORM_COLOR.
POINT_SHADER = "POINT_UNIFORM_COLOR" if bpy.app.version >= (4, 5, 0) else "UNIFORM_COLOR"


# -- Geometry Nodes groups (post-deformation correctives) --------------------------------------------------------
# The node-group interface API (``NodeTree.interface``) is the same on 4.2–5.x; node type names and socket
# names are looked up here so a rename in a later Blender has one place to change.

def clear_node_group(ng) -> None:
    """Remove every node and interface socket of a node group."""
    ng.nodes.clear()
    ng.interface.clear()


def new_interface_socket(ng, name: str, in_out: str, socket_type: str):
    """Add a group input/output socket (``in_out`` ``'INPUT'``/``'OUTPUT'``)."""
    return ng.interface.new_socket(name=name, in_out=in_out, socket_type=socket_type)


def interface_input_identifier(ng, index: int) -> str:
    """The identifier of the group's ``index``-th input socket (the key of a Geometry Nodes modifier's value)."""
    inputs = [item for item in ng.interface.items_tree if item.item_type == "SOCKET" and item.in_out == "INPUT"]
    return inputs[index].identifier


def socket(sockets, name: str):
    """The enabled socket called ``name`` (older node versions keep disabled per-type twins of a socket)."""
    for s in sockets:
        if s.name == name and getattr(s, "enabled", True):
            return s
    for s in sockets:
        if s.identifier == name:
            return s
    raise KeyError(f"no socket {name!r} on this Blender ({bpy.app.version_string})")


def named_attribute_node(ng, data_type: str, name: str):
    """A Named Attribute node reading ``name`` as ``data_type`` (``'INT'``, ``'FLOAT_VECTOR'``, …)."""
    node = ng.nodes.new("GeometryNodeInputNamedAttribute")
    node.data_type = data_type
    socket(node.inputs, "Name").default_value = name
    return node


def sample_index_node(ng, data_type: str):
    """A Sample Index node on the point domain."""
    node = ng.nodes.new("GeometryNodeSampleIndex")
    node.data_type = data_type
    node.domain = "POINT"
    return node


def store_attribute_node(ng, data_type: str, name: str):
    """A Store Named Attribute node writing ``name`` on the point domain."""
    node = ng.nodes.new("GeometryNodeStoreNamedAttribute")
    node.data_type = data_type
    node.domain = "POINT"
    socket(node.inputs, "Name").default_value = name
    return node



def modifier_input_path(mod, identifier: str) -> str:
    """Data path (from the object) of a Geometry Nodes modifier's input value, for a driver: an ID property
    ``modifiers["M"]["Socket_2"]`` up to 5.0, ``modifiers["M"].properties.inputs.Socket_2.value`` from 5.1."""
    if hasattr(mod, "properties"):
        return getattr(mod.properties.inputs, identifier).path_from_id("value")
    return f'modifiers["{mod.name}"]["{identifier}"]'


def set_modifier_input(mod, identifier: str, value) -> None:
    """Set a Geometry Nodes modifier's input value (see :func:`modifier_input_path`)."""
    if hasattr(mod, "properties"):
        getattr(mod.properties.inputs, identifier).value = value
    else:
        mod[identifier] = value
