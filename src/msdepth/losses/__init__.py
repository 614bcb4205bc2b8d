"""The training objectives: appearance terms per variant, Monodepth's and Monodepth2's losses."""
