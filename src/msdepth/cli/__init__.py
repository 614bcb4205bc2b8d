"""The ``msdepth`` command's subcommands: predict, optimum, export-onnx, export-folder,
experiments, example."""
