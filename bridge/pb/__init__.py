"""Generated protobuf code for schemas/*.proto: do not edit, run tools/gen_proto.py."""
