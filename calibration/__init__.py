"""Hand-eye calibration: the Park–Martin solver (``park_martin``), residuals and outlier rejection
(``residuals``), the ChArUco board (``board``), the capture routine (``routine``) and calibration files
(``files``: ``load_hand_eye`` reads what ``kitchenbot calibrate`` writes)."""
