"""Pictures: Gantt charts, cost curves, maps with paths and spatial-cost heat maps."""
