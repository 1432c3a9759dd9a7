"""softpinn.symbolic.derivation"""
