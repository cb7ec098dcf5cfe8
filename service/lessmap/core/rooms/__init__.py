"""Rooms: a windowed normalized cut of the frame stream, confirmed by familiarity, areas named."""
