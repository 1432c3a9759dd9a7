"""softpinn.symbolic.recorded._csv"""
