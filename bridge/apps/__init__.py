"""One module per tankviz command, each with its parser beside its handler."""
