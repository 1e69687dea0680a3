from setuptools import setup

package_name = 'pkm_sim_hw'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='PKM controller developers',
    maintainer_email='pkm-dev@pkm-controller.org',
    description=(
        'Simulated PKM hardware: plant dynamics, drives, encoders, '
        'compliance, faults, and the simulation node.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sim_hw_node = pkm_sim_hw.sim_hw_node:main',
            'hold_controller_node = pkm_sim_hw.hold_controller_node:main',
        ],
    },
)
