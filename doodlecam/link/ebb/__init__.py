"""EiBotBoard (AxiDraw, EggBot): the .ebb command stream, the board's LM arithmetic, its emulator and the serial link."""
