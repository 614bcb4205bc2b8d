"""The networks: Monodepth's VGG, Monodepth2's ResNet depth and pose networks, model files."""
