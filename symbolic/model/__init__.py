"""softpinn.symbolic.model._true_model"""
