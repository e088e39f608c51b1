"""Thesis reproductions (the rooftop experiment of paper 2) and the closed-loop demo."""
