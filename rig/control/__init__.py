"""Control laws of thesis chapters 6-7: joint controllers, the cooperative controller, the arm's own impedance goal."""
