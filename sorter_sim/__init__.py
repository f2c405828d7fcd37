"""sorter_sim: the parcel sorter cell simulation (model core, scenes, node, tools)."""
