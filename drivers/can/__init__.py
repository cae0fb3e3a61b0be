"""CAN protocol of the Z1 arm gateway and the flame igniter board (DBC + counter/checksum codec)."""
