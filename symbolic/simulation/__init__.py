"""softpinn.symbolic.simulation"""
