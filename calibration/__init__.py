"""Hand-eye calibration of the wrist camera.

``park_martin`` solves AX = XB (Park & Martin 1994) for eye-in-hand and eye-to-hand mounts; ``residuals`` gives
pair residuals, board spread and robust outlier rejection; ``refine`` optionally refines X on the corner pixels;
``board`` defines, renders and detects the ChArUco board; ``routine`` plans viewpoints and captures through the
Arm and Camera interfaces; ``files`` writes/reads the result YAML (``load_hand_eye``) and recorded samples;
``synthetic`` makes sample sets with a known answer; ``bench`` prints accuracy tables.
"""
