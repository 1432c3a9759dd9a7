"""softpinn.bridge.figures"""
