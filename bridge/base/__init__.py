"""softpinn.bridge.base"""
